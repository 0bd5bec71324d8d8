"""Paper Table 1: every agent type's evaluation success in both simulation arenas.

A row per point (agent type at its settings) of the final actors (not kept snapshots);
cells are mean ± 95 % t interval over seeds and the IQM with its bootstrap interval. The
paper's claims are tested seed by seed: its ordering of adjacent rows, the AfP effects and
ATD3+AfDP over the baselines. A claim pairs each row of the better type with the row of
the other type at the same settings, else with the row whose settings agree with it on
every setting both name and differ in the fewest others ("differs:" names those).
Training success per 50 episodes shows when each type learns.
"""

from __future__ import annotations

import numpy as np

import envs
from advisor_jax import stats
from advisor_jax.analysis.items.base import (
    ADVISOR_LEVEL,
    ARENAS,
    PAPER_TABLE1,
    Item,
    cell,
    comparison,
    figure,
    interval_note,
    iqm_cell,
    markdown_table,
    ordered,
    point_record,
    scores,
    seeds_with_ci,
    shared_label,
    shared_text,
    simulated,
)
from advisor_jax.analysis.runs import Point

BLOCK = 50  # training episodes per column of the learning table
PAPER_ORDERING = (
    ("ATD3+AfDP", "ADDPG+AfDP"),
    ("ADDPG+AfDP", "ADDPG+AfP"),
    ("ADDPG+AfP", "ADDPG+AfD"),
    ("ADDPG+AfD", "ADDPG"),
    ("ADDPG", "DDPG"),
)
AFP_EFFECTS = (("ADDPG+AfP", "ADDPG"), ("ADDPG+AfDP", "ADDPG+AfD"), ("ATD3+AfDP", "ATD3+AfD"))
OVER_BASELINES = (("ATD3+AfDP", "LfD"), ("ATD3+AfDP", "MCP+MF"))  # §6.2
CLAIMS = (
    ("ordering", PAPER_ORDERING),
    ("AfP effect", AFP_EFFECTS),
    ("over baseline", OVER_BASELINES),
)


def rows_of(points: list[Point]) -> list[Point]:
    return ordered(p for p in simulated(points) if not p.snapshot)


def partner(row: Point, other: str, rows: list[Point]) -> Point | None:
    """The row of type ``other`` at ``row``'s budget closest to ``row``'s settings: none of
    the settings both name may differ (the same arena, motion model, switches...), and of
    those, the one that names the fewest settings the other does not (a setting only one
    type has, such as ATD3's policy delay, is then named as what "differs")."""
    same = [r for r in rows if r.agent == other and r.budget == row.budget]
    compatible = [
        r
        for r in same
        if all(r.label[k] == row.label[k] for k in r.label.keys() & row.label.keys())
    ]
    return min(compatible, key=lambda r: len(r.label.keys() ^ row.label.keys()), default=None)


def claims(rows: list[Point]) -> list[dict]:
    out = []
    for kind, pairs in CLAIMS:
        for better, worse in pairs:
            for row in (r for r in rows if r.agent == better):
                other = partner(row, worse, rows)
                if other is None:
                    continue
                diffs = {a: comparison(row, other, a) for a in ARENAS}
                if not any(diffs.values()):
                    continue
                differs = sorted(
                    k for k in {*row.label, *other.label} if row.label.get(k) != other.label.get(k)
                )
                out.append(
                    {
                        "kind": kind,
                        "better": row.text(),
                        "worse": other.text(),
                        "episodes": row.budget,
                        "differs": differs,
                        **diffs,
                    }
                )
    return out


def learning_blocks(point: Point) -> list[float] | None:
    """Training success (% of episodes reaching the goal, all seeds) per ``BLOCK`` episodes."""
    outcome = point.episodes("outcome")
    if outcome is None:
        return None
    return [
        float(100 * np.mean(outcome[:, k : k + BLOCK] == envs.GOAL))
        for k in range(0, outcome.shape[1], BLOCK)
    ]


def table1(points: list[Point], context) -> Item | None:
    rows = rows_of(points)
    if not rows:
        return None
    found = claims(rows)
    record = {"points": [], "claims": found}
    table = []
    shared = tuple(shared_label(rows))
    for r in rows:
        speed = scores(r, "training", "collision_speed")
        below = sum(v < ADVISOR_LEVEL for v in scores(r, "training"))
        diverged = sum(s.evaluation["training"]["success"] is None for s in r.seeds.values())
        paper = PAPER_TABLE1.get(r.agent)
        blocks = learning_blocks(r)
        record["points"].append(
            {
                **point_record(r),
                "seeds_below_advisor": below,
                "eval_collision_speed": cell(speed, 1.0),
                "training_success_per_50": blocks,
                "paper": paper,
            }
        )
        table.append(
            (
                r.text(skip=shared),
                r.budget,
                f"{len(r.seeds)}" + (f" ({diverged} diverged)" if diverged else ""),
                *(f"{cell(scores(r, a))} / {iqm_cell(scores(r, a))}" for a in ARENAS),
                below,
                cell(speed, 1.0) if speed else "–",
                f"{paper[0]:.1f} / {paper[1]:.1f}" if paper else "–",
            )
        )
    lines = [
        shared_text(rows) + " "
        f"Evaluation success (%) per seed of the final actors: {interval_note(rows)} / IQM "
        "[95 % stratified-bootstrap interval]; every row on the same evaluation episodes.",
        "",
        *markdown_table(
            [
                "agent (settings beyond the preset)",
                "episodes",
                "seeds",
                "training env: mean / IQM",
                "validation env: mean / IQM",
                f"seeds below {100 * ADVISOR_LEVEL:g} %",
                "collision speed, eval (m/s)",
                "paper (train / val)",
            ],
            table,
            align="lr",
        ),
        "",
    ]
    lines += _new_episodes_lines(rows, record)
    lines += _claim_lines(found)
    lines += _learning_lines(rows)
    return Item(
        "table1",
        "Table 1: success of each agent type (simulation)",
        record,
        _plot(rows),
        lines,
        rows,
    )


def _new_episodes_lines(rows: list[Point], record: dict) -> list[str]:
    """Where every row's runs record per-episode outcomes: each row's success with the
    interval for new seeds *and* new evaluation episodes (the table's ± holds the episodes
    fixed), also into ``record["points"][k][arena]["seeds_and_episodes"]``."""
    found = [{a: r.seeds_and_episodes(a) for a in ARENAS} for r in rows]
    if any(iv is None for row in found for iv in row.values()):
        return []
    table = []
    for r, row, point in zip(rows, found, record["points"], strict=True):
        for arena, iv in row.items():
            point[arena]["seeds_and_episodes"] = {"mean": iv.estimate, "ci95": [iv.low, iv.high]}
        table.append((r.text(skip=tuple(shared_label(rows))),
                      *(stats.format_interval(iv, scale=100) for iv in row.values())))  # fmt: skip
    return [
        "The same success with the 95 % interval for new seeds and new evaluation episodes "
        "alike (`stats.seeds_and_episodes_interval`): what a comparison with numbers from "
        "other episodes, the paper's, must read.",
        "",
        *markdown_table(["agent", "training env", "validation env"], table, align="lr"),
        "",
    ]


def _claim_lines(found: list[dict]) -> list[str]:
    """The paper's claims as a markdown table (none: no lines)."""
    if not found:
        return []
    return [
        "The paper's claims, seed by seed: better − worse in success points, mean ± 95 % "
        "interval (`holds` above 0, `reversed` below), and P(better > worse) over all "
        "pairs of seeds:",
        "",
        *markdown_table(
            [
                "claim",
                "better > worse",
                "seeds",
                "training env",
                "P(>) training",
                "validation env",
                "P(>) validation",
            ],
            [
                (
                    c["kind"],
                    f"{c['better']} > {c['worse']}"
                    + (f" (differs: {', '.join(c['differs'])})" if c["differs"] else ""),
                    (c["training"] or {}).get("seeds", "–"),
                    *(
                        x
                        for a in ARENAS
                        for x in (
                            (c[a] or {}).get("text", "–"),
                            f"{c[a]['probability_of_improvement']:.2f}" if c[a] else "–",
                        )
                    ),
                )
                for c in found
            ],
            align="llrrrrr",
        ),
        "",
    ]


def _learning_lines(rows: list[Point]) -> list[str]:
    """Training success per block of episodes, a row per point with metrics."""
    learned = [(r, b) for r in rows if (b := learning_blocks(r))]
    if not learned:
        return []
    n = max(len(b) for _, b in learned)
    last = max(r.budget for r, _ in learned)
    return [
        f"Training success per {BLOCK} episodes (% of all seeds' episodes that reached "
        "the goal; exploration and, with AfD, the advisor acting):",
        "",
        *markdown_table(
            ["agent", *(f"{BLOCK * k + 1}–{min(BLOCK * (k + 1), last)}" for k in range(n))],
            [(r.text(), *(f"{v:.0f}" for v in b)) for r, b in learned],
        ),
        "",
    ]


def _plot(rows: list[Point]):
    fig, axes = figure(1, 1, width=max(8.0, 0.9 * len(rows) + 3), height=5.0)
    ax = axes[0, 0]
    colors = {"training": "tab:blue", "validation": "tab:orange"}
    for x, r in enumerate(rows):
        for k, arena in enumerate(ARENAS):
            values = [100 * v for v in scores(r, arena)]
            seeds_with_ci(
                ax,
                x + (k - 0.5) * 0.35,
                values,
                colors[arena],
                label=f"{arena} env" if x == 0 else None,
                width=0.12,
            )
            if r.agent in PAPER_TABLE1:
                ax.scatter(
                    x + (k - 0.5) * 0.35,
                    PAPER_TABLE1[r.agent][k],
                    marker="_",
                    s=250,
                    color="black",
                    label="paper" if x == 0 and k == 0 else None,
                )
    ax.axhline(100 * ADVISOR_LEVEL, color="grey", ls=":", lw=1, label="advisor's level")
    ax.set_xticks(range(len(rows)), [r.text() for r in rows], rotation=25, ha="right", fontsize=8)
    ax.set_ylabel("evaluation success (%)")
    ax.set_ylim(-3, 103)
    ax.set_title(f"Table 1: success per seed (dots), {interval_note(rows)} (bars)", fontsize=10)
    ax.grid(alpha=0.3, axis="y")
    ax.legend(fontsize=8)
    return fig
