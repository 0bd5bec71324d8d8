"""What every report item shares: its result, point records, per-seed drawing, the paper's
names and numbers, and markdown tables."""

from __future__ import annotations

import dataclasses
import math
import re
from collections.abc import Iterable, Sequence
from typing import Any

import numpy as np

from advisor_jax import stats
from advisor_jax.agent.config import PAPER_AGENTS, parse_agent
from advisor_jax.analysis.runs import Point, _show

ARENAS = ("training", "validation")
BASELINES = ("LfD", "MCP+MF")
ORDER = (*PAPER_AGENTS, *BASELINES, "brax-SAC", "brax-PPO", "TD3", "ATD3", "ATD3+AfD")
ADVISOR_LEVEL = 0.5  # the advisor's own success (results/advisor.md): a seed below it collapsed
PAPER_TABLE1 = {  # success %, training / validation environment (paper Table 1)
    "DDPG": (72.2, 71.3),
    "ADDPG": (78.3, 77.1),
    "ADDPG+AfD": (81.3, 79.3),
    "ADDPG+AfP": (84.5, 83.0),
    "ADDPG+AfDP": (88.1, 85.2),
    "ATD3+AfDP": (90.8, 89.4),
    "LfD": (80.2, 80.7),
    "MCP+MF": (82.3, 80.1),
}
# Settings that scale with the budget in the paper's programs (N_T = 50 % of N_total, ...).
BUDGET_SHARES = (
    "advisor_episodes",
    "demo_episodes",
    "random_episodes",
    "mpc_episodes",
    "dagger_episodes",
)


@dataclasses.dataclass
class Item:
    """One paper item: ``<name>.json`` (``record``), ``<name>.png`` and report.md lines."""

    name: str
    title: str
    record: dict
    figure: Any
    lines: list[str]
    points: list[Point]  # the points it shows (their runs give commands and provenance)


def rank(agent: str) -> tuple:
    return (ORDER.index(agent) if agent in ORDER else len(ORDER), agent)


def ordered(points: Iterable[Point]) -> list[Point]:
    """By agent type (the paper's order), budget, then settings with numbers compared as
    numbers (N_T = 50 before 100)."""
    return sorted(points, key=lambda p: (rank(p.agent), p.budget, natural_key(p.text())))


def natural_key(text: str) -> tuple:
    """``text`` split into numbers (compared by value) and the words between them."""
    parts = re.split(r"(\d+(?:\.\d+)?(?:e-?\d+)?)", text)
    return tuple((0, float(s), "") if i % 2 else (1, 0.0, s) for i, s in enumerate(parts))


def uses_advisor_data(agent: str) -> bool:
    try:
        return parse_agent(agent).advisor_data
    except ValueError:
        return False


def simulated(points: Iterable[Point]) -> list[Point]:
    """Points trained and evaluated in the simulation arenas (Table 1, Figs 6-11)."""
    return [p for p in points if p.arena != "physical" and in_both_arenas(p)]


def in_both_arenas(point: Point) -> bool:
    """Whether the point's runs were scored in the training and the validation arena."""
    return all(a in next(iter(point.seeds.values())).evaluation for a in ARENAS)


def key_without(point: Point, names: Sequence[str]) -> tuple:
    """The point's agent and settings except ``names`` (what a series holds constant)."""
    return (point.agent, tuple((k, v) for k, v in sorted(point.settings.items()) if k not in names))


def shared_label(points: Sequence[Point]) -> dict:
    """The settings (beyond the preset) every one of ``points`` has alike."""
    if not points:
        return {}
    first = points[0].label
    return {k: v for k, v in first.items() if all(p.label.get(k) == v for p in points)}


def shared_text(points: Sequence[Point]) -> str:
    """One sentence naming the presets and the settings every row shares."""
    presets = sorted({p.preset for p in points})
    shared = shared_label(points)
    text = f"Preset {', '.join(f'`{p}`' for p in presets)}"
    if shared:
        text += "; every row also has " + ", ".join(f"{k}={_show(v)}" for k, v in shared.items())
    return text + "."


def point_record(point: Point, arenas: Sequence[str] = ARENAS, key: str = "success") -> dict:
    """A point in an item's JSON: who, at which settings, and per arena its per-seed scores
    with mean, 95 % t interval, IQM and its bootstrap interval."""
    record = {
        "agent": point.agent,
        "episodes": point.budget,
        "preset": point.preset,
        "settings": {k: _json(v) for k, v in point.label.items()},
        "seeds": len(point.seeds),
        "seed_list": list(point.seeds),
        "snapshot_seeds": [s for s, r in point.seeds.items() if r.snapshot],
    }
    for arena in arenas:
        values = list(point.scores(arena, key).values())
        record[arena] = {"per_seed": values, **stats.summary(values)}
    return record


def point_summary(point: Point) -> dict:
    """One row of an item's flat ``points`` list (``pandas.DataFrame(record["points"])``):
    ``point_record`` without the per-seed detail, per arena it was evaluated in its mean
    success and 95 % t interval."""
    row = {
        "agent": point.agent,
        "episodes": point.budget,
        "settings": {k: _json(v) for k, v in point.label.items()},
        "seeds": len(point.seeds),
    }
    for arena in dict.fromkeys(a for r in point.seeds.values() for a in r.evaluation):
        if values := scores(point, arena):
            interval = stats.t_interval(values)
            row[arena] = {"mean": interval.estimate, "ci95": [interval.low, interval.high]}
    return row


def _json(value):
    return list(value) if isinstance(value, tuple) else value


def scores(point: Point, arena: str, key: str = "success") -> list[float]:
    return [v for v in point.scores(arena, key).values() if v is not None]


def cell(values: Sequence[float], scale: float = 100.0) -> str:
    """``84.5 ± 4.8`` (mean and t interval; no interval below 3 seeds)."""
    return stats.format_interval(stats.t_interval(values), scale=scale)


def iqm_cell(values: Sequence[float], scale: float = 100.0) -> str:
    iv = stats.iqm_interval(values)
    if iv.n == 0:
        return "–"
    if iv.n < stats.MIN_SEEDS_FOR_INTERVAL:
        return f"{scale * iv.estimate:.1f}"
    return f"{scale * iv.estimate:.1f} [{scale * iv.low:.1f}, {scale * iv.high:.1f}]"


def paired_cell(p: stats.Paired | None, scale: float = 100.0) -> str:
    if p is None:
        return "–"
    return f"{stats.format_interval(p.interval, scale=scale)} ({p.verdict})"


def comparison(x: Point, y: Point, arena: str, better: str = "above") -> dict | None:
    """X − Y in ``arena``: paired by seed (points and 95 % interval) and the probability of
    improvement P(X > Y) over all seeds; None below two shared seeds."""
    paired = stats.paired_difference(x.scores(arena), y.scores(arena), better)
    if paired is None:
        return None
    poi = stats.probability_of_improvement(scores(x, arena), scores(y, arena))
    iv = paired.interval
    return {
        "seeds": len(paired.seeds),
        "mean": 100 * iv.estimate,
        "ci95": [100 * iv.low, 100 * iv.high],
        "half": 100 * iv.half,
        "verdict": paired.verdict,
        "probability_of_improvement": poi.estimate,
        "poi_ci95": [poi.low, poi.high],
        "text": paired_cell(paired),
    }


def markdown_table(header: Sequence[str], rows: Iterable[Sequence[Any]], align: str = "lr"):
    """A markdown table as lines; ``align``: "l" or "r" per column, the last for the rest."""
    width = len(header)
    align = (align + align[-1] * width)[:width]
    lines = [
        "| " + " | ".join(header) + " |",
        "|" + "|".join("---:" if a == "r" else "---" for a in align) + "|",
    ]
    lines += ["| " + " | ".join(str(c) for c in row) + " |" for row in rows]
    return lines


def line_colour(i: int, n: int):
    """The colour of the i-th of n lines: matplotlib's ten cycle colours while they last,
    twenty (tab20) beyond, so that up to 20 lines in one legend stay apart."""
    if n <= 10:
        return f"C{i}"
    from matplotlib import colormaps

    return colormaps["tab20"](i % 20)


def seeds_with_ci(ax, x: float, values, color, label=None, log_x=False, width=0.15) -> None:
    """Per-seed values as jittered dots around ``x`` and the mean with its 95 % t interval
    (a bar only from ``stats.MIN_SEEDS_FOR_INTERVAL`` seeds on)."""
    v = stats.finite(values)
    if v.size == 0:
        return
    jitter = np.random.default_rng(v.size).uniform(-width / 2, width / 2, v.size)
    xs = x * 10.0**jitter if log_x else x + jitter
    ax.scatter(xs, v, s=10, color=color, alpha=0.45, linewidths=0)
    iv = stats.t_interval(v)
    shown = iv.n >= stats.MIN_SEEDS_FOR_INTERVAL and not math.isnan(iv.half)
    ax.errorbar(
        x,
        iv.estimate,
        yerr=iv.half if shown else None,
        fmt="o",
        ms=5,
        capsize=4,
        color=color,
        markeredgecolor="black",
        label=label,
    )


def interval_note(points: Sequence[Point]) -> str:
    fewest = min((len(p.seeds) for p in points), default=0)
    note = "mean ± 95 % Student-t interval over seeds"
    if fewest < stats.MIN_SEEDS_FOR_INTERVAL:
        note += f" (none drawn below {stats.MIN_SEEDS_FOR_INTERVAL} seeds)"
    return note


def episode_axis(ax, label: str = "episode") -> None:
    """An x axis of episode counts: labelled, whole numbers only (a short run drew 1.5)."""
    from matplotlib.ticker import MaxNLocator

    ax.set_xlabel(label)
    ax.xaxis.set_major_locator(MaxNLocator(integer=True))


def figure(rows: int = 1, cols: int = 1, width: float = 5.0, height: float = 3.8, **kw):
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    return plt.subplots(
        rows,
        cols,
        figsize=(width * cols, height * rows),
        squeeze=False,
        constrained_layout=True,
        **kw,
    )
