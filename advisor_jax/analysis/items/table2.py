"""Paper Tables 2 and 3: agents trained in the physical arena for 100, 150 and 200 episodes
(Table 2), and the collision speeds of those trained longest (Table 3).

Per agent type, its longest run gives the row and its kept actors (``--snapshot-episodes``)
the smaller budgets; a shorter run of the same type gives that budget instead (‡: a
baseline's prior phases scale with its budget, so the longer run's actor there is not what
a run of that length ends with). † marks a budget the baseline's prior-knowledge phases
fill (no RL episode yet). ATD3+AfDP, the paper's best, is compared with every other type
seed by seed. Table 3 pools every collision episode of a type's seeds (mean ± sd, the
paper's measure) from each agent's mean, spread and count; the advisor's row comes from an
``advisor-jax evaluate --policy advisor --arena physical --json`` file in a report folder.
"""

from __future__ import annotations

import numpy as np

from advisor_jax import stats
from advisor_jax.agent.advisor_quality import changed_knobs
from advisor_jax.agent.baselines import prior_episodes
from advisor_jax.agent.config import hparams_from_row, train_config_from_dict
from advisor_jax.analysis.items.base import (
    Item,
    cell,
    comparison,
    episode_axis,
    figure,
    interval_note,
    markdown_table,
    ordered,
    point_record,
    scores,
    seeds_with_ci,
    shared_label,
    shared_text,
)
from advisor_jax.analysis.runs import Point

ARENA = "physical"
PAPER_TABLE2 = {  # success % at 100 / 150 / 200 training episodes (paper Table 2)
    "DDPG": (30.7, 39.0, 45.0),
    "ADDPG": (33.0, 43.3, 48.3),
    "ADDPG+AfDP": (45.0, 59.3, 70.3),
    "ATD3+AfDP": (48.3, 69.3, 75.3),
    "LfD": (37.0, 48.3, 60.7),
    "MCP+MF": (34.7, 45.3, 53.3),
}
PAPER_TABLE3 = {  # collision speed m/s, mean ± sd, agents trained for 200 episodes
    "Advisor": (0.36, 0.24),
    "DDPG": (0.43, 0.26),
    "ADDPG": (0.38, 0.21),
    "ADDPG+AfDP": (0.21, 0.16),
    "ATD3+AfDP": (0.15, 0.13),
    "LfD": (0.19, 0.21),
    "MCP+MF": (0.35, 0.25),
}
BEST = "ATD3+AfDP"
NO_RL, SEPARATE = "†", "‡"


def pooled_collision_speed(point: Point) -> dict:
    """Mean ± sd over every collision episode of the point's seeds, from each seed's
    collision rate (× episodes: its count), mean and sd; and the number of collisions."""
    episodes = next(iter(point.seeds.values())).run.evaluation[ARENA]["episodes"]
    counts, means, sds = [], [], []
    for s in point.seeds.values():
        ev = s.evaluation[ARENA]
        count = round((ev["collision"] or 0.0) * episodes)
        if count and ev["collision_speed"] is not None:
            if ev["collision_speed_sd"] is None:
                raise ValueError(
                    f"{s.run.path}: collision_speed_sd missing; re-evaluate it "
                    "(advisor-jax reevaluate)"
                )
            counts.append(count)
            means.append(ev["collision_speed"])
            sds.append(ev["collision_speed_sd"])
    total = int(sum(counts))
    out = {"collisions": total, "episodes": episodes * len(point.seeds), "mean": None, "sd": None}
    if total:
        c, m, s = (np.asarray(x, np.float64) for x in (counts, means, sds))
        mean = float(np.sum(c * m) / total)
        out.update(mean=mean, sd=float(np.sqrt(np.sum(c * (s**2 + (m - mean) ** 2)) / total)))
    return out


def prior(point: Point) -> float | None:
    """Episodes a baseline's phases take before RL (None for the paper's agents)."""
    run = next(iter(point.seeds.values())).run
    agent = train_config_from_dict(run.config).agent
    if agent.baseline is None:
        return None
    return float(prior_episodes(agent.baseline, hparams_from_row(agent, point.settings))[0])


def type_rows(points: list[Point]) -> tuple[list[dict], list[str]]:
    """Per agent type: {budget: point}, with shorter runs in place of kept actors."""
    by_type: dict[str, list[Point]] = {}
    for p in ordered(p for p in points if p.arena == ARENA):
        by_type.setdefault(p.agent, []).append(p)
    rows, notes = [], []
    for agent, found in by_type.items():
        finals = sorted((p for p in found if not p.snapshot), key=lambda p: -p.budget)
        if not finals:
            continue
        main = finals[0]
        row = {"agent": agent, "main": main, "budgets": {main.budget: main}, "separate": {}}
        row["budgets"] |= {p.budget: p for p in found if p.snapshot and p.settings == main.settings}
        for p in finals[1:]:
            if p.budget in row["separate"] or p.budget == main.budget:
                notes.append(f"a second {agent} run of {p.budget} episodes ({p.text()}), left out")
                continue
            row["separate"][p.budget] = row["budgets"].get(p.budget)  # the kept actor, if any
            row["budgets"][p.budget] = p
        row["budgets"] = dict(sorted(row["budgets"].items()))
        rows.append(row)
    return rows, notes


def advisor_row_label(record: dict) -> str:
    """ "Advisor", or with the advisor's spec and knobs where it is not the paper's rule as it
    is (an ``advisor-jax evaluate --policy advisor --json`` record)."""
    spec = (record.get("advisor") or {}).get("spec", "rule")
    knobs = changed_knobs(record.get("quality") or {})
    return "Advisor" if spec == "rule" and not knobs else f"Advisor ({', '.join([spec, *knobs])})"


def table2(points: list[Point], context) -> Item | None:
    rows, notes = type_rows(points)
    if not rows:
        return None
    budgets = sorted({n for r in rows for n in r["budgets"]})
    best = next((r for r in rows if r["agent"] == BEST), None)
    record = {"budgets": budgets, "agents": [], "versus_best": [], "afp_collision_speed": []}
    table, table3 = [], []
    shared = tuple(shared_label([r["main"] for r in rows]))
    advisor = context.advisors.get(ARENA)
    if advisor:
        p = PAPER_TABLE3["Advisor"]
        collisions = round(advisor["collision_rate"] * advisor["episodes"])
        table3.append(
            (
                advisor_row_label(advisor),
                _speed(advisor["mean_collision_speed"], advisor["collision_speed_sd"]),
                f"{collisions} of {advisor['episodes']}",
                f"{p[0]:.2f} ± {p[1]:.2f}",
            )
        )
    for r in rows:
        final = r["budgets"][budgets[-1]] if budgets[-1] in r["budgets"] else r["main"]
        r["collision"] = pooled_collision_speed(final)
        marks = {
            n: (NO_RL if (q := prior(p)) is not None and n <= q else "")
            + (SEPARATE if n in r["separate"] else "")
            for n, p in r["budgets"].items()
        }
        paper = PAPER_TABLE2.get(r["agent"])
        table.append(
            (
                r["main"].text(skip=("episodes", *shared)),
                *(
                    cell(scores(r["budgets"][n], ARENA)) + f" {marks[n]}".rstrip()
                    if n in r["budgets"]
                    else "–"
                    for n in budgets
                ),
                " / ".join(f"{v:.1f}" for v in paper) if paper else "–",
            )
        )
        c, p3 = r["collision"], PAPER_TABLE3.get(r["agent"])
        table3.append(
            (
                r["agent"],
                _speed(c["mean"], c["sd"]),
                f"{c['collisions']} of {c['episodes']}",
                f"{p3[0]:.2f} ± {p3[1]:.2f}" if p3 else "–",
            )
        )
        kept = {n: (point_record(k, (ARENA,)) if k else None) for n, k in r["separate"].items()}
        record["agents"].append(
            {
                "agent": r["agent"],
                "marks": marks,
                "prior_episodes": prior(r["main"]),
                "budgets": {n: point_record(p, (ARENA,)) for n, p in r["budgets"].items()},
                "kept_actor_replaced": kept,
                "collision_speed": c,
                "paper": {"success": paper, "collision_speed": p3},
            }
        )
        for n in budgets:
            if best and r is not best and n in r["budgets"] and n in best["budgets"]:
                diff = comparison(best["budgets"][n], r["budgets"][n], ARENA)
                if diff:
                    record["versus_best"].append({"other": r["agent"], "episodes": n, **diff})
    record["afp_collision_speed"] = _afp_collisions(rows, budgets[-1])
    lines = [
        shared_text([r["main"] for r in rows]) + " "
        f"Success in the {ARENA} arena (%), {interval_note([r['main'] for r in rows])}; "
        f"{NO_RL}: the baseline's prior phases fill that budget (no RL yet); {SEPARATE}: a "
        "separate run of that many episodes in place of the kept actor.",
        "",
        *markdown_table(
            ["agent", *(f"{n} episodes" for n in budgets), "paper (100 / 150 / 200)"], table
        ),
        "",
    ]
    lines += _comparison_lines(record, table3, budgets[-1])
    record["notes"] = notes
    record["advisor"] = advisor
    return Item(
        "table2",
        "Tables 2 and 3: the physical arena",
        record,
        _plot(rows, budgets),
        lines,
        [p for r in rows for p in r["budgets"].values()],
    )


def _comparison_lines(record: dict, table3: list, final: int) -> list[str]:
    """ATD3+AfDP against each type, Table 3 and its AfP claim, as markdown."""
    lines = []
    if record["versus_best"]:
        lines += [
            f"{BEST} − other type, success points, seed by seed:",
            "",
            *markdown_table(
                ["other type", "episodes", "seeds", f"{BEST} − other", f"P({BEST} > other)"],
                [
                    (
                        c["other"],
                        c["episodes"],
                        c["seeds"],
                        c["text"],
                        f"{c['probability_of_improvement']:.2f}",
                    )
                    for c in record["versus_best"]
                ],
            ),
            "",
        ]
    lines += [
        f"Table 3: collision speed after {final} episodes, mean ± sd over every "
        "collision episode of the type's seeds:",
        "",
        *markdown_table(["agent", "collision speed (m/s)", "collisions", "paper (m/s)"], table3),
        "",
    ]
    if record["afp_collision_speed"]:
        lines += [
            "AfP types collide slower (Table 3's claim): AfP type − other type in each seed's "
            "mean collision speed (m/s), seeds where both collided (`holds` below 0):",
            "",
            *markdown_table(
                ["AfP type", "other type", "seeds", "difference (m/s)"],
                [
                    (c["afp"], c["other"], c["seeds"], c["text"])
                    for c in record["afp_collision_speed"]
                ],
            ),
            "",
        ]
    return lines


def _afp_collisions(rows: list[dict], budget: int) -> list[dict]:
    out = []
    finals = {r["agent"]: r["budgets"].get(budget) for r in rows}
    afp = [a for a in finals if "AfP" in a or "AfDP" in a]
    for a in afp:
        for b in (b for b in finals if b not in afp):
            x, y = finals[a], finals[b]
            if x is None or y is None:
                continue
            mean_speed = lambda p: {
                s: (
                    r.evaluation[ARENA]["collision_speed"]  # noqa: E731
                    if r.evaluation[ARENA]["collision"]
                    else None
                )
                for s, r in p.seeds.items()
            }
            paired = stats.paired_difference(mean_speed(x), mean_speed(y), better="below")
            if paired is not None:
                out.append(
                    {
                        "afp": a,
                        "other": b,
                        "seeds": len(paired.seeds),
                        "mean": paired.interval.estimate,
                        "ci95": list(paired.interval[1:3]),
                        "verdict": paired.verdict,
                        "text": f"{stats.format_interval(paired.interval, digits=2)} "
                        f"({paired.verdict})",
                    }
                )
    return out


def _speed(mean, sd) -> str:
    return "none: no collision" if mean is None else f"{mean:.2f} ± {sd:.2f}"


def _plot(rows: list[dict], budgets: list[int]):
    fig, axes = figure(1, 1, width=8.0, height=5.0)
    ax = axes[0, 0]
    step = (budgets[-1] - budgets[0]) / max(len(budgets) - 1, 1) if len(budgets) > 1 else 50
    width = 0.6 * step / max(len(rows), 1)
    colors = [f"C{i}" for i in range(10)]
    for i, r in enumerate(rows):
        offset = (i - (len(rows) - 1) / 2) * width
        for j, (n, p) in enumerate(r["budgets"].items()):
            values = [100 * v for v in scores(p, ARENA)]
            seeds_with_ci(
                ax,
                n + offset,
                values,
                colors[i % 10],
                label=None if j else r["agent"],
                width=width * 0.6,
            )
        if r["agent"] in PAPER_TABLE2:
            ax.plot(
                (100, 150, 200),
                PAPER_TABLE2[r["agent"]],
                ls=":",
                marker="x",
                color=colors[i % 10],
                lw=1,
            )
    ax.plot([], [], ls=":", marker="x", color="0.3", label="paper (Table 2)")
    ax.set_xticks(budgets)
    episode_axis(ax, "training episodes")
    ax.set_ylabel(f"success in the {ARENA} arena (%)")
    ax.set_ylim(-3, 103)
    ax.grid(alpha=0.3)
    ax.legend(fontsize=8, ncol=2, loc="lower right")
    ax.set_title("Table 2: success per seed (dots), mean ± 95 % t interval", fontsize=10)
    return fig
