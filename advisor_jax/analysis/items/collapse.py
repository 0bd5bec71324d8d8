"""Why seeds collapse, from the per-agent learner diagnostics training logs per chunk
(metrics.npz ``log/...``), per seed of every point:

* **collapsed**: evaluation success in the training arena below the advisor's own (0.5);
* **saturation**: the share of the actor's output heads within 0.01 of their bound first
  reaches ``SATURATED`` (listed for Eq. 2 agents only: the DPG drives DDPG's heads to the
  bounds where Q is highest, not a failure);
* **critic blow-up**: the critic loss first exceeds ``BLOWUP`` × its median over logged
  chunks 5-24 (the first chunks are the first updates' transient);
* **Eq. 2 step**: the largest batch-mean step ‖β∇ₐQ‖ (or its scale-free form), before clipping;
* **Q above the return bound**: the batch-mean Q(S, A) first exceeds the largest discounted
  return any policy can collect (``envs.reward.return_bounds``), i.e. overestimation;
* **collapse from**: the first 50-episode block below 25 % training success after one at or
  above it.

Each "first" is the training episode at that chunk. ``final_diagnostics`` gives each
diagnostic's value in the chunk in which an agent completed its budget.
"""

from __future__ import annotations

import numpy as np

import envs
from advisor_jax.agent.config import parse_agent
from advisor_jax.analysis.items.base import (
    ADVISOR_LEVEL,
    ARENAS,
    Item,
    cell,
    episode_axis,
    figure,
    markdown_table,
    ordered,
    scores,
)
from advisor_jax.analysis.runs import Point, Seed
from envs.reward import return_bounds
from envs.state import EnvConfig

BLOCK, SETTLE, SATURATED, BLOWUP = 50, 5, 0.5, 100.0
DIAGNOSTICS = ("advisor/replaced", "diag/step", "diag/grad_q_rms", "diag/q_gain", "diag/saturated")


def _first(mask: np.ndarray, episode_at_chunk: np.ndarray) -> int | None:
    hits = np.flatnonzero(mask)
    return int(episode_at_chunk[hits[0]]) if hits.size else None


def collapse_episode(blocks: list[float]) -> int | None:
    for b, success in enumerate(blocks):
        if success < 0.25 and max(blocks[:b], default=0.0) >= 0.25:
            return BLOCK * b
    return None


def final_diagnostics(seed: Seed) -> dict:
    """Each diagnostic's last finite value up to the chunk in which the agent completed its
    budget (later chunks only wait for the rest of its population)."""
    m = seed.run.metrics() or {}
    steps = m.get("log/step", np.zeros(0))
    if steps.size == 0:
        return {name: None for name in DIAGNOSTICS}
    if seed.snapshot:  # one env per agent: the steps of its first `budget` episodes
        done = int(np.sum(m["length"][seed.index, : seed.budget]))
    else:
        done = int(m["env_steps"][seed.index])
    last = min(int(np.searchsorted(steps, done)), steps.size - 1)
    out = {}
    for name in DIAGNOSTICS:
        values = m.get(f"log/{name}", np.zeros((seed.index + 1, 0)))[seed.index, : last + 1]
        kept = values[np.isfinite(values)]
        out[name] = float(kept[-1]) if kept.size else None
    return out


def analyse_seed(point: Point, seed: Seed) -> dict | None:
    """The module docstring's measures for one agent; None without training logs."""
    m = seed.run.metrics()
    if m is None or "log/diag/saturated" not in m:
        return None
    i = seed.index
    ends = np.cumsum(m["length"][i])
    episode_at_chunk = np.searchsorted(ends, m["log/step"], side="right")
    saturated, critic, step = (
        np.asarray(m[f"log/{k}"][i], np.float64)
        for k in ("diag/saturated", "loss/critic", "diag/step")
    )
    q = (
        np.asarray(m["log/q/mean"][i], np.float64)
        if "log/q/mean" in m
        else np.full(critic.shape, np.nan)
    )
    bound = float(return_bounds(EnvConfig(), point.settings["gamma"])[1])
    window = critic[SETTLE : SETTLE + 20]
    early = np.nanmedian(window) if np.isfinite(window).any() else np.nan
    late = np.arange(critic.size) >= SETTLE
    outcome = m["outcome"][i]
    blocks = [
        float(np.mean(outcome[k : k + BLOCK] == envs.GOAL))
        for k in range(0, outcome.shape[0], BLOCK)
    ]
    success = seed.evaluation["training"]["success"]
    eq2 = parse_agent(point.agent).advisor_target

    def peak(x):
        return float(np.nanmax(x)) if np.isfinite(x).any() else None

    return {
        "seed": seed.seed,
        "run": str(seed.run.path),
        "blocks": blocks,
        "eval_training": success,
        "collapsed": success is not None and success < ADVISOR_LEVEL,
        "max_saturated": peak(saturated),
        "saturation_at": _first(saturated >= SATURATED, episode_at_chunk),
        "eq2": eq2,
        "critic_blowup_at": _first(late & (critic > BLOWUP * early), episode_at_chunk),
        "max_critic_ratio": peak(critic) / early if np.isfinite(early) and peak(critic) else None,
        "max_step": peak(step),
        "q_bound": bound,
        "max_q": peak(q),
        "q_over_bound_at": _first(q > bound, episode_at_chunk),
        "collapse_at": collapse_episode(blocks),
        "_series": (
            episode_at_chunk,
            saturated,
            critic / early if np.isfinite(early) else critic,
            q,
        ),
    }


def analyse(point: Point) -> list[dict]:
    return [a for s in point.seeds.values() if (a := analyse_seed(point, s)) is not None]


def collapse(points: list[Point], context) -> Item | None:
    rows = [
        (p, analyse(p))
        for p in ordered(
            p
            for p in points
            if not p.snapshot and "training" in next(iter(p.seeds.values())).evaluation
        )
    ]
    rows = [(p, a) for p, a in rows if a]
    if not rows:
        return None
    summary = [_point_summary(p, agents) for p, agents in rows]
    flagged = [(p, a) for p, agents in rows for a in agents if _flagged(a)]
    public = lambda a: {k: v for k, v in a.items() if not k.startswith("_")}  # noqa: E731
    record = {
        "thresholds": {
            "advisor_level": ADVISOR_LEVEL,
            "saturated": SATURATED,
            "blowup": BLOWUP,
            "settle_chunks": SETTLE,
        },
        "points": summary,
        "agents": [{"point": p.text(), **public(a)} for p, agents in rows for a in agents],
    }
    lines = [
        f"Per point: seeds below the advisor's {100 * ADVISOR_LEVEL:g} % (collapsed), and those "
        f"whose heads saturated (≥ {SATURATED:g}, Eq. 2 agents), whose critic loss passed "
        f"{BLOWUP:g}× its early median, or whose batch-mean Q passed the return bound.",
        "",
        *markdown_table(
            [
                "point",
                "episodes",
                "seeds",
                "training env (%)",
                "validation env (%)",
                "worst seed (%)",
                "collapsed",
                "saturated",
                "critic blow-up",
                "Q > bound",
            ],
            [
                (
                    s["point"],
                    s["episodes"],
                    s["seeds"],
                    s["training"],
                    s["validation"],
                    "–" if s["worst_seed"] is None else f"{100 * s['worst_seed']:.0f}",
                    s["collapsed"],
                    s["saturated"],
                    s["critic_blowup"],
                    s["q_over_bound"],
                )
                for s in summary
            ],
        ),
        "",
    ]
    lines += _flagged_lines(flagged)
    return Item(
        "collapse",
        "Collapsed seeds and the learner diagnostics",
        record,
        _plot(rows),
        lines,
        [p for p, _ in rows],
    )


def _point_summary(p: Point, agents: list[dict]) -> dict:
    """A point's row: success, worst seed, and how many seeds each measure flagged."""

    def count(key):
        return sum(a[key] is not None for a in agents)

    finite = [a["eval_training"] for a in agents if a["eval_training"] is not None]
    return {
        "point": p.text(),
        "episodes": p.budget,
        "seeds": len(agents),
        **{a: cell(scores(p, a)) for a in ARENAS},
        "worst_seed": min(finite, default=None),
        "collapsed": sum(a["collapsed"] for a in agents),
        "saturated": count("saturation_at"),
        "critic_blowup": count("critic_blowup_at"),
        "q_over_bound": count("q_over_bound_at"),
    }


def _flagged(a: dict) -> bool:
    """Collapsed, saturated (Eq. 2 agents), blown up or overestimating."""
    return (
        a["collapsed"]
        or (a["saturation_at"] is not None and a["eq2"])
        or a["critic_blowup_at"] is not None
        or a["q_over_bound_at"] is not None
    )


def _flagged_lines(flagged: list) -> list[str]:
    """Every flagged agent with the episode at which each measure began."""
    if not flagged:
        return []

    def show(v):
        return "–" if v is None else v

    return [
        "Every such agent (episode at which each began; success per 50 training episodes):",
        "",
        *markdown_table(
            [
                "point",
                "seed",
                "success per 50 episodes",
                "eval %",
                "saturated from",
                "critic blow-up from",
                "max Eq. 2 step",
                "Q > bound from",
                "max batch Q",
                "collapse from",
            ],
            [
                (
                    p.text(),
                    a["seed"],
                    " ".join(f"{100 * b:.0f}" for b in a["blocks"]),
                    "–" if a["eval_training"] is None else f"{100 * a['eval_training']:.1f}",
                    show(a["saturation_at"]),
                    show(a["critic_blowup_at"]),
                    "–" if a["max_step"] is None else f"{a['max_step']:.2f}",
                    show(a["q_over_bound_at"]),
                    "–" if a["max_q"] is None else f"{a['max_q']:.1f}",
                    show(a["collapse_at"]),
                )
                for p, a in flagged
            ],
        ),
        "",
    ]


def _plot(rows):
    fig, axes = figure(1, 4, width=4.8, height=4.2)
    axes = axes[0]
    for g, (_, agents) in enumerate(rows):
        y = [a["eval_training"] for a in agents if a["eval_training"] is not None]
        jitter = np.linspace(-0.15, 0.15, len(y)) if len(y) > 1 else [0.0]
        colours = ["tab:red" if v < ADVISOR_LEVEL else "tab:blue" for v in y]
        axes[0].scatter(g + np.asarray(jitter), y, c=colours, s=14, zorder=3)
        for a in agents:
            episode, saturated, critic, q = a["_series"]
            colour, alpha = ("tab:red", 0.9) if a["collapsed"] else ("tab:blue", 0.2)
            axes[1].plot(episode, saturated, color=colour, alpha=alpha, lw=0.8)
            axes[2].plot(episode, critic, color=colour, alpha=alpha, lw=0.8)
            axes[3].plot(episode, q, color=colour, alpha=alpha, lw=0.8)
    axes[0].axhline(ADVISOR_LEVEL, color="grey", ls="--", lw=1)
    axes[0].set_xticks(
        range(len(rows)), [p.text() for p, _ in rows], rotation=35, ha="right", fontsize=6
    )
    axes[0].set_ylabel("evaluation success, training arena")
    axes[0].set_title("per seed (red: below the advisor)", fontsize=9)
    for ax, title in zip(
        axes[1:],
        ("actor heads saturated (share)", "critic loss / its early median", "batch-mean Q(S, A)"),
        strict=True,
    ):
        episode_axis(ax, "training episode")
        ax.set_ylabel(title)
        ax.set_title(title, fontsize=9)
    axes[2].set_yscale("log")
    axes[3].set_yscale("symlog", linthresh=1.0)
    for bound in {a["q_bound"] for _, agents in rows for a in agents}:
        axes[3].axhline(bound, color="grey", ls="--", lw=1)
    return fig
