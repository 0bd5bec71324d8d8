"""How good must the advisor be? Each agent's success against its advisor's own success.

From runs trained with ``--eval-advisor`` (``experiments/paper/advisor_quality.toml``), whose
every agent's advisor was also evaluated alone on the agents' evaluation episodes
(eval_advisor.json, docs/advisors.md). Per agent type that uses the advisor and per budget
(N_total and the kept actors' N, ``--snapshot-episodes 100 200``): evaluation success
against the advisor's own success, both arenas, mean ± 95 % t interval over seeds with the
seeds as dots; a line per agent type and advisor (the rule and a trained policy under their
quality knobs), y = x (as good as its advisor), and the agent type's control without the
advisor as a band where the runs hold it (ADDPG for ADDPG+AfD, +AfP and +AfDP, ATD3 for
ATD3+AfDP, DDPG for LfD). The table adds, per advisor, the agent minus its control seed by
seed (the same seeds and episodes): where AfD and AfP help, where they stop helping, and
whether either hurts.
"""

from __future__ import annotations

from pathlib import PurePath

import numpy as np

from advisor_jax import stats
from advisor_jax.agent.advisor_quality import AdvisorQuality, changed_knobs
from advisor_jax.agent.hparams import PRIOR_HPARAMS
from advisor_jax.agent.settings import flat_fields, flat_items
from advisor_jax.analysis.items.base import (
    ARENAS,
    Item,
    cell,
    comparison,
    figure,
    interval_note,
    line_colour,
    markdown_table,
    point_record,
    rank,
    scores,
    seeds_with_ci,
    simulated,
)
from advisor_jax.analysis.runs import Point

CONTROL = {"ADDPG+AfD": "ADDPG", "ADDPG+AfP": "ADDPG", "ADDPG+AfDP": "ADDPG",
           "ATD3+AfD": "ATD3", "ATD3+AfDP": "ATD3", "LfD": "DDPG"}  # fmt: skip
KNOBS = tuple(flat_items(AdvisorQuality()))
ADVISOR_SETTINGS = ("advisor", *KNOBS)
# What a control may differ in from the agent type it is the control of.
NOT_COMPARED = (
    *ADVISOR_SETTINGS,
    "baseline",
    *(n for cls in PRIOR_HPARAMS.values() for n in flat_fields(cls())),
)


def advisor_success(point: Point, arena: str) -> float | None:
    """The advisor's own success (the same for every seed of the point: one advisor, the
    same episodes and draws); None where a seed lacks it."""
    values = [s.advisor.get(arena, {}).get("success") for s in point.seeds.values()]
    if not values or any(v is None for v in values):
        return None
    return float(np.mean(values))


def advisor_label(point: Point) -> str:
    """``rule``, ``atd3_quick_300ep, advisor_random=0.2`` (the spec's last path part)."""
    spec = str(point.settings["advisor"])
    name = spec if ":" in spec and "/" not in spec else PurePath(spec).name or spec
    return ", ".join([name, *changed_knobs({k: point.settings[k] for k in KNOBS})])


def _series_key(point: Point) -> tuple:
    return (rank(point.agent), point.budget, _without(point, ADVISOR_SETTINGS))


def _without(point: Point, names) -> tuple:
    return tuple((k, v) for k, v in sorted(point.settings.items()) if k not in names)


def _control(point: Point, points: list[Point]) -> Point | None:
    name = CONTROL.get(point.agent)
    mine = _without(point, NOT_COMPARED)
    matches = [
        p
        for p in points
        if p.agent == name and p.budget == point.budget and _without(p, NOT_COMPARED) == mine
    ]
    return min(matches, key=lambda p: (len(p.label), p.text()), default=None)


def advisor_quality(points: list[Point], context) -> Item | None:
    sim = simulated(points)
    advised = [
        p
        for p in sim
        if p.agent in CONTROL and all(advisor_success(p, a) is not None for a in ARENAS)
    ]
    if not advised:
        return None
    series: dict[tuple, list[Point]] = {}
    for p in advised:
        series.setdefault(_series_key(p), []).append(p)
    series = dict(sorted(series.items(), key=lambda kv: kv[0][:2]))
    record, lines, controls = {"series": []}, [], {}
    for members in series.values():
        members.sort(key=lambda p: advisor_success(p, "training"))
        first = members[0]
        control = _control(first, sim)
        if control is not None:
            controls[id(control)] = control
        entry = {"agent": first.agent, "budget": first.budget, "advisors": [],
                 "control": None if control is None else point_record(control)}  # fmt: skip
        rows = []
        for p in members:
            versus = {a: comparison(p, control, a) if control else None for a in ARENAS}
            entry["advisors"].append({
                "advisor": p.settings["advisor"],
                "knobs": {k: p.settings[k] for k in KNOBS},
                "label": advisor_label(p),
                "advisor_success": {a: advisor_success(p, a) for a in ARENAS},
                "point": point_record(p),
                "versus_control": versus,
            })  # fmt: skip
            rows.append((
                advisor_label(p),
                *(f"{100 * advisor_success(p, a):.1f}" for a in ARENAS),
                *(cell(scores(p, a)) for a in ARENAS),
                *((versus[a] or {}).get("text", "–") for a in ARENAS),
            ))  # fmt: skip
        record["series"].append(entry)
        versus_name = f"{control.agent} (no advisor)" if control else "no control in these runs"
        lines += [
            f"**{first.text(skip=ADVISOR_SETTINGS)}, {first.budget} episodes**; control: "
            f"{versus_name}" + (f", {cell(scores(control, 'training'))} / "
                                f"{cell(scores(control, 'validation'))} %" if control else ""),
            "",
            *markdown_table(
                ["advisor", *(f"advisor {a} (%)" for a in ARENAS),
                 *(f"agent {a} (%)" for a in ARENAS),
                 *(f"agent − control, {a} (points)" for a in ARENAS)],
                rows,
                align="lr",
            ),
            "",
        ]  # fmt: skip
    record["controls"] = [point_record(c) for c in controls.values()]
    shown = [p for m in series.values() for p in m] + list(controls.values())
    note = (
        f"Evaluation success (%) against the advisor's own success on the same episodes, "
        f"{interval_note(shown)}; agent − control: paired by seed, 95 % t interval (verdict)."
    )
    figure_ = _plot(series, controls)
    title = "Advisor quality: agent success against the advisor's own success"
    return Item("advisor_quality", title, record, figure_, [note, "", *lines], shown)


def _plot(series: dict, controls: dict):
    budgets = sorted({key[1] for key in series})
    fig, axes = figure(len(budgets), len(ARENAS), width=5.2, height=4.2)
    agents = sorted({m[0].agent for m in series.values()}, key=lambda a: rank(a))
    colour = {a: line_colour(i, len(agents)) for i, a in enumerate(agents)}
    for (_, budget, _), members in series.items():
        row = budgets.index(budget)
        by_advisor: dict[str, list[Point]] = {}
        for p in members:
            by_advisor.setdefault(str(p.settings["advisor"]), []).append(p)
        for k, group in enumerate(by_advisor.values()):
            for ax, arena in zip(axes[row], ARENAS, strict=True):
                xs = [100 * advisor_success(p, arena) for p in group]
                means = []
                for p, x in zip(group, xs, strict=True):
                    values = [100 * v for v in scores(p, arena)]
                    seeds_with_ci(ax, x, values, colour[p.agent], width=1.2)
                    means.append(stats.t_interval(values).estimate)
                order = np.argsort(xs)
                label = f"{group[0].agent} · {advisor_label(group[0]).split(',')[0]}"
                style = {"color": colour[group[0].agent], "ls": ("-", "--", ":", "-.")[k % 4]}
                ax.plot(np.asarray(xs)[order], np.asarray(means)[order], lw=1.2, label=label,
                        **style)  # fmt: skip
    for row, budget in enumerate(budgets):
        for ax, arena in zip(axes[row], ARENAS, strict=True):
            _controls(ax, [c for c in controls.values() if c.budget == budget], arena)
            ax.plot(
                [0, 100], [0, 100], color="grey", lw=0.8, ls=":", label="as good as its advisor"
            )
            ax.set_xlim(0, 100)
            ax.set_ylim(-3, 103)
            ax.set_xlabel(f"advisor's own success, {arena} env (%)")
            ax.set_ylabel(f"agent success after {budget} episodes, {arena} env (%)")
            ax.grid(alpha=0.3)
    # one legend under the panels: inside them it covered the points of the lowest lines
    handles, labels = axes[0][0].get_legend_handles_labels()
    fig.legend(handles, labels, loc="outside lower center", ncol=3, fontsize=7)
    fig.suptitle("Agent success against the advisor's own success (same episodes)", fontsize=10)
    return fig


def _controls(ax, controls: list[Point], arena: str) -> None:
    for i, control in enumerate(sorted(controls, key=lambda c: rank(c.agent))):
        iv = stats.t_interval([100 * v for v in scores(control, arena)])
        grey = ("0.25", "0.5", "0.7")[i % 3]
        ax.axhline(iv.estimate, color=grey, lw=1.0, ls="--", label=f"{control.agent} (no advisor)")
        if iv.n >= stats.MIN_SEEDS_FOR_INTERVAL:
            ax.axhspan(iv.low, iv.high, color=grey, alpha=0.12, lw=0)
