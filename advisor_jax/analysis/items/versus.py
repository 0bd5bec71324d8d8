"""Comparisons of settings, seed by seed.

* ``versus`` (``advisor-jax report --versus NAME[=VALUE]``): every pair of points of one
  agent type and budget that differ in setting NAME alone (``clip_q_target``,
  ``precision``, ``policy_delay``, ...); treatment − control, where the treatment is the
  side with NAME = VALUE (default: the side that differs from its preset, else the larger
  value). Per side: success, worst seed, seeds below the advisor, seeds whose batch-mean Q
  passed the return bound, the largest batch-mean Q; the paired difference and P(treatment
  > control).
* ``afp`` (the advisor in policy updating against its control): each point of ADDPG+AfP,
  ADDPG+AfDP or ATD3+AfDP against the agent type without AfP (ADDPG+AfD, ATD3+AfD) at the
  same budget and settings but β: paired over shared seeds, else by Welch's interval; with
  each point's learner diagnostics in its last training chunk; success against β per mode
  of Eq. 2's step (literal or scale-free, Â clipped or not).
"""

from __future__ import annotations

import math

from advisor_jax import stats
from advisor_jax.analysis.items.base import (
    ADVISOR_LEVEL,
    ARENAS,
    Item,
    cell,
    comparison,
    figure,
    markdown_table,
    ordered,
    point_record,
    scores,
    seeds_with_ci,
)
from advisor_jax.analysis.items.collapse import DIAGNOSTICS, analyse, final_diagnostics
from advisor_jax.analysis.runs import Point, _show

CONTROL_OF = {"ADDPG+AfP": "ADDPG+AfD", "ADDPG+AfDP": "ADDPG+AfD", "ATD3+AfDP": "ATD3+AfD"}
MODES = ("beta", "beta_normalize", "clip_actor_target")


def parse_versus(item: str) -> tuple[str, object]:
    name, _, value = item.partition("=")
    return name.strip(), (value.strip() or None)


def _treatment_first(a: Point, b: Point, name: str, value) -> bool:
    if value is not None:
        return _show(a.settings[name]) == value or str(a.settings[name]) == value
    if (name in a.label) != (name in b.label):
        return name in a.label
    return a.settings[name] > b.settings[name]


def _side(point: Point) -> dict:
    analysed = analyse(point)
    max_q = [a["max_q"] for a in analysed if a["max_q"] is not None]
    training = scores(point, "training")
    return {
        **point_record(point),
        "worst": 100 * min(training) if training else None,
        "below_advisor": sum(v < ADVISOR_LEVEL for v in training),
        "q_over_bound": sum(a["q_over_bound_at"] is not None for a in analysed),
        "max_q": max(max_q, default=None),
    }


def versus(points: list[Point], context) -> Item | None:
    found = []
    for item in context.versus:
        name, value = parse_versus(item)
        for a in ordered(points):
            for b in ordered(points):
                if a is b or a.agent != b.agent or a.budget != b.budget:
                    continue
                differ = {k for k in a.settings if a.settings[k] != b.settings[k]}
                if differ == {name} and _treatment_first(a, b, name, value):
                    found.append((name, a, b))
    if not found:
        return None
    record, table = {"pairs": []}, []
    for name, t, c in found:
        diffs = {a: comparison(t, c, a) for a in ARENAS if a in _arenas(t)}
        sides = {"treatment": _side(t), "control": _side(c)}
        record["pairs"].append(
            {
                "setting": name,
                "agent": t.agent,
                "episodes": t.budget,
                "treatment_value": _show(t.settings[name]),
                "control_value": _show(c.settings[name]),
                **sides,
                "difference": diffs,
            }
        )

        def pair(key, fmt, sides=sides):
            return " / ".join(
                "–" if (v := sides[s][key]) is None else format(v, fmt)
                for s in ("treatment", "control")
            )

        table.append(
            (
                t.text(skip=(name,)),
                f"{name}: {_show(t.settings[name])} vs {_show(c.settings[name])}",
                " / ".join(cell(scores(p, "training")) for p in (t, c)),
                *((diffs.get(a) or {}).get("text", "–") for a in ARENAS),
                " / ".join(
                    f"{d['probability_of_improvement']:.2f}" if d else "–"
                    for d in (diffs.get(a) for a in ARENAS)
                ),
                pair("worst", ".0f"),
                pair("below_advisor", "d"),
                pair("q_over_bound", "d"),
                pair("max_q", ".1f"),
            )
        )
    lines = [
        "Treatment − control, seed by seed (same initial networks and evaluation episodes), "
        "success points, mean ± 95 % interval; P(>): P(treatment > control) over all pairs of "
        "seeds, training / validation; per side (treatment / control): the worst seed's "
        f"success, seeds below {100 * ADVISOR_LEVEL:g} %, seeds whose batch-mean Q passed the "
        "return bound, the largest batch-mean Q.",
        "",
        *markdown_table(
            [
                "agent",
                "setting",
                "training success (%)",
                "difference, training",
                "difference, validation",
                "P(>)",
                "worst seed (%)",
                "below advisor",
                "Q > bound",
                "max Q",
            ],
            table,
        ),
        "",
    ]
    shown = [p for _, t, c in found for p in (t, c)]
    return Item(
        "versus", "Settings compared seed by seed", record, _plot_pairs(found), lines, shown
    )


def _arenas(point: Point) -> list[str]:
    return list(next(iter(point.seeds.values())).evaluation)


def _plot_pairs(found):
    fig, axes = figure(
        1, len(ARENAS), width=max(5.0, 1.3 * len(found) + 2), height=4.5, sharey=True
    )
    for ax, arena in zip(axes[0], ARENAS, strict=True):
        for i, (_, t, c) in enumerate(found):
            ts, cs = t.scores(arena), c.scores(arena)
            for s in sorted(set(ts) & set(cs)):
                if ts[s] is not None and cs[s] is not None:
                    ax.plot(
                        [i - 0.18, i + 0.18],
                        [100 * cs[s], 100 * ts[s]],
                        lw=0.8,
                        alpha=0.5,
                        color="tab:red" if ts[s] < cs[s] else "tab:gray",
                    )
            seeds_with_ci(
                ax,
                i - 0.18,
                [100 * v for v in scores(c, arena)],
                "tab:orange",
                label="control" if i == 0 else None,
                width=0.05,
            )
            seeds_with_ci(
                ax,
                i + 0.18,
                [100 * v for v in scores(t, arena)],
                "tab:blue",
                label="treatment" if i == 0 else None,
                width=0.05,
            )
        ax.set_xticks(
            range(len(found)),
            [
                f"{t.agent}\n{n}={_show(t.settings[n])} vs {_show(c.settings[n])}"
                for n, t, c in found
            ],
            fontsize=7,
        )
        ax.axhline(100 * ADVISOR_LEVEL, color="black", ls=":", lw=1)
        ax.set_title(f"{arena} arena: each seed, control → treatment", fontsize=9)
        ax.set_ylabel("evaluation success (%)")
        ax.grid(alpha=0.3, axis="y")
        ax.legend(fontsize=7)
    return fig


def _control(point: Point, points: list[Point]) -> Point | None:
    control = CONTROL_OF.get(point.agent)
    matches = [
        p
        for p in points
        if p.agent == control
        and p.budget == point.budget
        and all(
            p.settings[k] == v
            for k, v in point.settings.items()
            if k not in ("beta", "beta_normalize")
        )
    ]
    return min(matches, key=lambda p: (len(p.label), p.text()), default=None)


def _mode(point: Point) -> str:
    if point.agent not in CONTROL_OF:
        return "no AfP"
    mode = "scale-free" if point.settings["beta_normalize"] else "literal"
    return mode + (", Â clipped" if point.settings["clip_actor_target"] else "")


def afp(points: list[Point], context) -> Item | None:
    controls = set(CONTROL_OF.values())
    shown = ordered(p for p in points if p.agent in CONTROL_OF and "training" in _arenas(p))
    if not shown:
        return None
    shown = ordered(
        [*shown, *(p for p in points if p.agent in controls and "training" in _arenas(p))]
    )
    record, table = {"points": []}, []
    for p in shown:
        control = _control(p, points) if p.agent in CONTROL_OF else None
        effect = {}
        if control is not None:
            for arena in ARENAS:
                welch = stats.welch_interval(scores(p, arena), scores(control, arena))
                effect[arena] = {
                    "welch": [welch.estimate, welch.low, welch.high],
                    "paired": comparison(p, control, arena),
                }
        diags = [final_diagnostics(s) for s in p.seeds.values()]
        mean_diag = {d: stats.t_interval([x[d] for x in diags]).estimate for d in DIAGNOSTICS}
        record["points"].append(
            {
                **point_record(p),
                "mode": _mode(p),
                "control": control.text() if control else None,
                "effect": effect,
                "diagnostics": mean_diag,
                "collapsed": {a: sum(v < ADVISOR_LEVEL for v in scores(p, a)) for a in ARENAS},
                "eval_timeout_training": stats.t_interval(
                    scores(p, "training", "timeout")
                ).estimate,
            }
        )
        table.append(
            (
                p.text(),
                p.budget,
                _mode(p),
                len(p.seeds),
                *(cell(scores(p, a)) for a in ARENAS),
                " / ".join(str(sum(v < ADVISOR_LEVEL for v in scores(p, a))) for a in ARENAS),
                *(_effect(effect.get(a)) for a in ARENAS),
                *(_num(mean_diag[d]) for d in DIAGNOSTICS),
                _num(stats.t_interval(scores(p, "training", "timeout")).estimate),
            )
        )
    lines = [
        "Each AfP point, its success (%), seeds below the advisor (training / validation), the "
        "AfP effect against its control (the type without AfP at the same budget and settings "
        "but β), success points: paired by seed where they share seeds (mean ± 95 %), else "
        "[Welch 95 % interval]; and the learner's diagnostics in each seed's last training "
        "chunk, mean over seeds (replaced share, ‖Eq. 2 step‖, rms ‖∇ₐQ‖, Q(s, a_adv) − "
        "Q(s, Â), saturated heads); the share of timeouts in the training-arena evaluation.",
        "",
        *markdown_table(
            [
                "point",
                "episodes",
                "mode",
                "seeds",
                "training (%)",
                "validation (%)",
                "collapsed",
                "AfP effect, training",
                "AfP effect, validation",
                *DIAGNOSTICS,
                "eval timeouts",
            ],
            table,
        ),
        "",
    ]
    return Item(
        "afp",
        "The advisor in policy updating against its control, by β",
        record,
        _plot_afp(shown, points),
        lines,
        shown,
    )


def _effect(effect) -> str:
    if not effect:
        return "–"
    if effect["paired"]:
        return effect["paired"]["text"]
    d, lo, hi = (100 * v for v in effect["welch"])
    return "–" if math.isnan(d) else f"{d:+.1f} [{lo:+.1f}, {hi:+.1f}]"


def _num(x) -> str:
    return "–" if x is None or not math.isfinite(x) else f"{x:.3g}"


def _plot_afp(shown: list[Point], points: list[Point]):
    shown = [p for p in shown if p.agent in CONTROL_OF]
    agents = list(dict.fromkeys(p.agent for p in shown))
    budgets = sorted({p.budget for p in shown}, reverse=True)
    columns = [(n, a) for n in budgets for a in ARENAS]
    fig, axes = figure(len(agents), len(columns), width=4.2, height=3.3, sharey=True)
    modes = sorted({_mode(p) for p in shown})
    for row, agent in enumerate(agents):
        for col, (n, arena) in enumerate(columns):
            ax = axes[row, col]
            for m, mode in enumerate(modes):
                offset = 10.0 ** (0.12 * (m - (len(modes) - 1) / 2))
                here = [p for p in shown if p.agent == agent and p.budget == n and _mode(p) == mode]
                for j, p in enumerate(here):
                    seeds_with_ci(
                        ax,
                        p.settings["beta"] * offset,
                        scores(p, arena),
                        f"C{m}",
                        label=None if j else mode,
                        log_x=True,
                        width=0.08,
                    )
            control = [p for p in points if p.agent == CONTROL_OF[agent] and p.budget == n]
            for c in sorted(control, key=lambda p: len(p.label))[:1]:
                iv = stats.t_interval(scores(c, arena))
                ax.axhspan(iv.low, iv.high, color="0.6", alpha=0.3, label=f"{c.agent} (control)")
                ax.axhline(iv.estimate, color="0.4", lw=1)
            ax.axhline(ADVISOR_LEVEL, color="red", ls="--", lw=0.8)
            ax.set_xscale("log")
            ax.set_ylim(-0.03, 1.03)
            ax.grid(alpha=0.3)
            ax.set_title(f"{agent}, {n} ep, {arena} arena", fontsize=9)
            ax.set_xlabel("β")
            ax.set_ylabel("evaluation success")
            ax.legend(fontsize=6)
    return fig
