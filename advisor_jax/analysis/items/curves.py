"""The paper's training curves, from each seed's per-episode metrics (metrics.npz):

* Fig. 8: reward per step, moving average over 150 episodes, mean ± sd over seeds, a line
  per point;
* Fig. 9: collision speed (mean |V| of the last three steps of a collision episode),
  moving average over 10 episodes, mean (solid) and ± sd (dotted), a panel per agent type;
* Fig. 10: the actor's firing rate (share of an episode's steps where the actor's action
  was executed), moving average over 30 episodes, mean ± sd, against Eq. (11)'s expected
  maximum (the run's ``expected_max_firing_rate``, already averaged over w = 30), for the
  agent types with the advisor in data collection.

The moving average is trailing and skips episodes without a value (a window with no
collision has no collision speed). Points are the final actors in the simulation arenas.
"""

from __future__ import annotations

import warnings

import numpy as np

from advisor_jax.analysis.items.base import (
    Item,
    episode_axis,
    figure,
    line_colour,
    ordered,
    simulated,
    uses_advisor_data,
)
from advisor_jax.analysis.runs import Point
from advisor_jax.training.reporting import moving_average

REWARD_WINDOW, COLLISION_WINDOW, FIRING_WINDOW = 150, 10, 30


def _mean_sd(values: np.ndarray, window: int) -> tuple[np.ndarray, np.ndarray]:
    smooth = moving_average(values, window)
    with warnings.catch_warnings():  # a window with no value anywhere: NaN, not a warning
        warnings.simplefilter("ignore", RuntimeWarning)
        return np.nanmean(smooth, axis=0), np.nanstd(smooth, axis=0)


def _with(points: list[Point], metric: str) -> list[tuple[Point, np.ndarray]]:
    out = []
    for p in ordered(q for q in simulated(points) if not q.snapshot):
        values = p.episodes(metric)
        if values is not None:
            out.append((p, values))
    return out


def _record(found, window: int, extra=None) -> dict:
    series = []
    for p, values in found:
        mean, sd = _mean_sd(values, window)
        entry = {
            "label": p.text(),
            "episodes": p.budget,
            "seeds": len(p.seeds),
            "mean": _list(mean),
            "sd": _list(sd),
        }
        if extra:
            entry |= extra(p)
        series.append(entry)
    return {"window": window, "series": series}


def _list(x: np.ndarray) -> list:
    return [None if not np.isfinite(v) else round(float(v), 5) for v in x]


def fig8(points: list[Point], context) -> Item | None:
    found = _with(points, "reward_per_step")
    if not found:
        return None
    fig, axes = figure(1, 1, width=9.0, height=5.0)
    ax = axes[0, 0]
    for i, (p, values) in enumerate(found):
        mean, sd = _mean_sd(values, REWARD_WINDOW)
        x = np.arange(1, mean.size + 1)
        label = f"{p.text()} (n={len(p.seeds)})"
        (line,) = ax.plot(x, mean, lw=1.2, color=line_colour(i, len(found)), label=label)
        ax.fill_between(x, mean - sd, mean + sd, color=line.get_color(), alpha=0.15)
    episode_axis(ax)
    ax.set_ylabel(f"reward per step (moving average, {REWARD_WINDOW} episodes)")
    ax.set_title("Fig. 8: reward per step, mean ± sd over seeds", fontsize=10)
    ax.grid(alpha=0.3)
    ax.legend(fontsize=7)
    note = (
        f"Reward per step, trailing moving average over {REWARD_WINDOW} episodes, mean ± "
        "standard deviation over seeds (the paper's measure); numbers per episode in the JSON."
    )
    return Item(
        "fig8",
        "Fig. 8: learning curves (reward per step)",
        _record(found, REWARD_WINDOW),
        fig,
        [note, ""],
        [p for p, _ in found],
    )


def fig9(points: list[Point], context) -> Item | None:
    found = _with(points, "collision_speed")
    if not found:
        return None
    types = list(dict.fromkeys(p.agent for p, _ in found))
    cols = min(4, len(types))
    rows = -(-len(types) // cols)
    fig, axes = figure(rows, cols, width=4.2, height=3.4, sharey=True)
    for ax in axes.flat[len(types) :]:
        ax.set_visible(False)
    for i, (p, values) in enumerate(found):
        ax = axes.flat[types.index(p.agent)]
        mean, sd = _mean_sd(values, COLLISION_WINDOW)
        x = np.arange(1, mean.size + 1)
        (line,) = ax.plot(x, mean, lw=1.0, color=line_colour(i, len(found)), label=p.text())
        ax.plot(x, mean + sd, ls=":", lw=0.8, color=line.get_color())
        ax.plot(x, np.maximum(mean - sd, 0), ls=":", lw=0.8, color=line.get_color())
        ax.set_title(p.agent, fontsize=9)
        episode_axis(ax)
        ax.grid(alpha=0.3)
        ax.legend(fontsize=6)
    for ax in axes[:, 0]:
        ax.set_ylabel(f"collision speed (m/s), MA {COLLISION_WINDOW}")
    fig.suptitle("Fig. 9: collision speed, mean (solid) ± sd (dotted) over seeds", fontsize=10)
    note = (
        f"Collision speed (mean |V| over the last three steps of an episode that ends in a "
        f"collision), trailing moving average over {COLLISION_WINDOW} episodes (episodes "
        "without a collision skipped), mean ± sd over seeds, a panel per agent type."
    )
    return Item(
        "fig9",
        "Fig. 9: collision speed during training",
        _record(found, COLLISION_WINDOW),
        fig,
        [note, ""],
        [p for p, _ in found],
    )


def fig10(points: list[Point], context) -> Item | None:
    """Left: the firing rate of one run per agent type (its preset's point at its longest
    budget) against Eq. (11). Right: every point's firing rate as a share of Eq. (11) while
    the advisor takes part, against N_T: one curve per type and budget reads as a figure,
    fifty do not."""
    found = [(p, v) for p, v in _with(points, "firing_rate") if uses_advisor_data(p.agent)]
    found = [(p, v) for p, v in found if p.episodes("expected_max_firing_rate") is not None]
    if not found:
        return None

    def expected(p):
        return np.nanmean(p.episodes("expected_max_firing_rate"), axis=0)

    record = _record(found, FIRING_WINDOW, lambda p: {"expected_max": _list(expected(p))})
    for entry, (p, _) in zip(record["series"], found, strict=True):
        n_t = int(p.settings["advisor_episodes"])
        mean = np.asarray([np.nan if v is None else v for v in entry["mean"]], np.float64)
        exp = np.asarray(entry["expected_max"], np.float64)
        inside = slice(min(FIRING_WINDOW, n_t), min(n_t, mean.size))
        with warnings.catch_warnings():
            warnings.simplefilter("ignore", RuntimeWarning)
            entry["share_of_expected_before_N_T"] = float(np.nanmean(mean[inside] / exp[inside]))

    agents = list(dict.fromkeys(p.agent for p, _ in found))
    color = {a: line_colour(i, len(agents)) for i, a in enumerate(agents)}
    fig, axes = figure(1, 2, width=5.5, height=4.4)
    ax = axes[0, 0]
    for agent in agents:  # its preset's point (fewest settings changed), longest budget
        p, values = min(
            ((q, v) for q, v in found if q.agent == agent),
            key=lambda qv: (len(qv[0].label), -qv[0].budget),
        )
        mean, sd = _mean_sd(values, FIRING_WINDOW)
        x = np.arange(1, mean.size + 1)
        ax.plot(x, mean, lw=1.2, color=color[agent], label=f"{p.text()}, {p.budget} ep")
        ax.fill_between(x, mean - sd, mean + sd, color=color[agent], alpha=0.15)
        ax.plot(x, expected(p), color=color[agent], ls="--", lw=1.0)
    ax.plot([], [], color="0.3", ls="--", label="Eq. (11): expected maximum")
    episode_axis(ax)
    ax.set_ylabel(f"actor's firing rate (moving average, {FIRING_WINDOW} episodes)")
    ax.set_ylim(-0.03, 1.03)
    ax.set_title("one run per type, mean ± sd over seeds", fontsize=9)
    ax.grid(alpha=0.3)
    ax.legend(fontsize=6)
    ax = axes[0, 1]
    budgets = sorted({p.budget for p, _ in found})
    markers = dict(zip(budgets, "os^Dv<>ph*", strict=False))
    for agent in agents:
        for n in budgets:
            here = [
                (p.settings["advisor_episodes"], e["share_of_expected_before_N_T"])
                for e, (p, _) in zip(record["series"], found, strict=True)
                if p.agent == agent
                and p.budget == n
                and np.isfinite(e["share_of_expected_before_N_T"])
            ]
            if here:
                xs, ys = zip(*sorted(here), strict=True)
                ax.plot(xs, ys, color=color[agent], marker=markers.get(n, "o"), lw=0.8, ms=4)
    for agent in agents:
        ax.plot([], [], color=color[agent], lw=2, label=agent)
    for n in budgets:
        ax.plot([], [], color="0.4", marker=markers.get(n, "o"), ls="", label=f"N_total = {n}")
    ax.set_xlabel("N_T (the advisor's terminal episode)")
    ax.set_ylabel("firing rate / Eq. (11) while the advisor takes part")
    ax.set_ylim(0, 1.03)
    ax.set_title("every point (points of one ε schedule share N_T)", fontsize=9)
    ax.grid(alpha=0.3)
    ax.legend(fontsize=6)
    fig.suptitle("Fig. 10: the actor's firing rate against Eq. (11)", fontsize=10)
    lines = [
        f"The actor's firing rate, trailing moving average over {FIRING_WINDOW} episodes, mean "
        "± sd over seeds, against Eq. (11)'s expected maximum (dashed). Mean ratio of the "
        "firing rate to Eq. (11) while the advisor takes part (episodes w..N_T):",
        "",
        *(
            f"- {e['label']}, {e['episodes']} ep: {_ratio(e['share_of_expected_before_N_T'])}"
            for e in record["series"]
        ),
        "",
    ]
    return Item(
        "fig10",
        "Fig. 10: the actor's firing rate against Eq. (11)",
        record,
        fig,
        lines,
        [p for p, _ in found],
    )


def _ratio(x: float) -> str:
    return "– (N_T below the window)" if not np.isfinite(x) else f"{x:.2f}"
