"""Issue 16, item 2: why seeds collapse, read from the per-agent diagnostics of real runs.

Reads finished run directories (run.json, metrics.npz, eval.json; ``advisor-jax train``
writes them, and ``--export`` of ``afp_study.py`` copies them) and, for every agent:

* its training success per block of 50 episodes and its evaluation success per arena;
* whether it **collapsed**: evaluation success in the training arena below the advisor's own
  (``--advisor-level``, 0.5: the advisor succeeds in about half of the episodes,
  results/advisor.md);
* which diagnostic went wrong, and at which training episode, from the per-chunk series
  that training logs for every agent (``log/diag/...`` in metrics.npz):
  **saturation**: the share of the actor's output heads within 0.01 of their bound first
  reaches ``--saturated`` (0.5); **critic blow-up**: the critic loss first exceeds
  ``--blowup`` (100) × its median over logged chunks 5-24 (the first chunks are the
  first updates' transient); **Eq. 2 step**: the
  largest batch-mean step length ‖β∇ₐQ‖ (or its scale-free form) in action units, before
  any clipping of Â (the box is 1 wide for V, 2 for ω); **Q above the return bound**: the
  batch-mean Q(S, A) first exceeds the largest discounted return any policy can collect in
  the arena (``envs.reward.return_bounds``: 17.5 at the paper's γ = 0.9), so the critic
  overestimates, and by how much (the largest batch-mean Q).

It then pools agents with the same settings (agent type, β, beta_normalize,
clip_actor_target) across runs and writes ``afp_collapse.md``, ``.json`` and ``.png``
(per-seed evaluation success per setting; the saturation, critic-loss and Q series of every
agent, collapsed ones in red) into ``--out``.

    python experiments/afp_collapse.py results/afp_collapse/run_data/* --out results
"""

from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path

import common
import numpy as np

from advisor_jax.agent.config import parse_agent
from advisor_jax.fileio import atomic_write_json
from advisor_jax.training.reporting import mean_ci95
from envs import GOAL
from envs.reward import return_bounds
from envs.state import EnvConfig

BLOCK = 50  # episodes per training-success block
SETTLE = 5  # logged chunks (of 1000 steps) before the critic loss's reference window
SETTINGS = ("beta", "beta_normalize", "clip_actor_target", "clip_q_target")
SATURATED = 0.5  # default --saturated: share of output heads at a bound
BLOWUP = 100.0  # default --blowup: critic loss over its early median


def first_episode(mask: np.ndarray, episode_at_chunk: np.ndarray) -> int | None:
    """Training episode at the first chunk where ``mask`` holds (None if never)."""
    hits = np.flatnonzero(mask)
    return int(episode_at_chunk[hits[0]]) if hits.size else None


def collapse_episode(blocks: list[float]) -> int | None:
    """First training episode of a 50-episode block below 25 % success after the agent had
    reached 25 % in an earlier block (a slow start is not a collapse); None if none."""
    for b, success in enumerate(blocks):
        if success < 0.25 and max(blocks[:b], default=0.0) >= 0.25:
            return BLOCK * b
    return None


def uses_eq2(agent: str) -> bool:
    """ADDPG / ATD3 regress the actor on Eq. 2's Â; DDPG / TD3 (and the baselines) follow
    the DPG, for which saturated heads are where Q is highest, not a failure."""
    return parse_agent(agent).advisor_target


def analyse_run(run_dir: Path, args) -> list[dict]:
    run = json.loads((run_dir / "run.json").read_text())
    metrics = np.load(run_dir / "metrics.npz")
    evaluation = json.loads((run_dir / "eval.json").read_text())
    outcome, length = metrics["outcome"], metrics["length"]
    steps = metrics["log/step"]  # env steps at the end of each chunk (one env per agent)
    rows = []
    for agent in run["agents"]:
        i = agent["index"]
        ends = np.cumsum(length[i])
        episode_at_chunk = np.searchsorted(ends, steps, side="right")  # completed by then
        saturated = metrics["log/diag/saturated"][i]
        critic = metrics["log/loss/critic"][i]
        step = metrics["log/diag/step"][i]
        q = metrics["log/q/mean"][i] if "log/q/mean" in metrics else np.full(critic.shape, np.nan)
        q_bound = float(return_bounds(EnvConfig(), float(agent.get("gamma", 0.9)))[1])
        window = critic[SETTLE : SETTLE + 20]  # after the first updates' transient
        early = np.nanmedian(window) if np.isfinite(window).any() else np.nan
        late = np.arange(critic.size) >= SETTLE
        blocks = [float(np.mean(outcome[i, k : k + BLOCK] == GOAL))
                  for k in range(0, outcome.shape[1], BLOCK)]  # fmt: skip
        eval_train = float(evaluation["training"]["success"][i])
        rows.append(
            dict(
                run=run_dir.name,
                agent=run["agent"],
                seed=int(agent["seed"]),
                **{k: float(agent.get(k, 0.0)) for k in SETTINGS},  # older runs: no clip_q
                blocks=blocks,
                last_block=blocks[-1],
                eval_training=eval_train,
                eval_validation=float(evaluation["validation"]["success"][i]),
                collapsed=eval_train < args.advisor_level,
                max_saturated=float(np.nanmax(saturated)) if np.isfinite(saturated).any() else None,
                saturation_at=first_episode(saturated >= args.saturated, episode_at_chunk),
                critic_blowup_at=first_episode(
                    late & (critic > args.blowup * early), episode_at_chunk
                ),
                max_critic_ratio=float(np.nanmax(critic) / early) if np.isfinite(early) else None,
                max_step=float(np.nanmax(step)) if np.isfinite(step).any() else None,
                q_bound=q_bound,
                max_q=float(np.nanmax(q)) if np.isfinite(q).any() else None,
                q_over_bound_at=first_episode(q > q_bound, episode_at_chunk),
                collapse_at=collapse_episode(blocks),
                preset=run.get("preset", "paper"),
                device=run.get("device"),
                created=run.get("created"),
                _saturated=saturated,
                _critic=critic / early if np.isfinite(early) else critic,
                _q=q,
                _episode=episode_at_chunk,
            )
        )
    return rows


def group_key(row: dict) -> tuple:
    return (row["agent"], *(row[k] for k in SETTINGS))


def label(key: tuple) -> str:
    agent, beta, norm, clip, clip_q = key
    q = ", Q̂ clipped" if clip_q else ""
    if not uses_eq2(agent):  # the DPG actor: β unused
        return f"{agent}{' (Q̂ clipped)' if clip_q else ''}"
    mode = "scale-free" if norm else "literal"
    return f"{agent} β={beta:g} {mode}{', Â clipped' if clip else ''}{q}"


def summarise(rows: list[dict]) -> list[dict]:
    groups: dict[tuple, list[dict]] = {}
    for row in rows:
        groups.setdefault(group_key(row), []).append(row)
    out = []
    for key, members in sorted(groups.items(), key=lambda kv: (kv[0][0], kv[0][1:])):
        seeds = sorted({m["seed"] for m in members})
        train, val = [m["eval_training"] for m in members], [m["eval_validation"] for m in members]
        m_t, h_t = mean_ci95(train)
        m_v, h_v = mean_ci95(val)
        out.append(
            dict(
                setting=label(key),
                agent=key[0],
                **dict(zip(SETTINGS, key[1:], strict=True)),
                seeds=seeds,
                runs=sorted({m["run"] for m in members}),
                eval_training=(m_t, h_t),
                eval_validation=(m_v, h_v),
                min_seed_training=min(train),
                last_block_mean=float(np.mean([m["last_block"] for m in members])),
                collapsed=sum(m["collapsed"] for m in members),
                saturated=sum(m["saturation_at"] is not None for m in members),
                critic_blowup=sum(m["critic_blowup_at"] is not None for m in members),
                q_over_bound=sum(m["q_over_bound_at"] is not None for m in members),
            )
        )
    return out


def plot(path: Path, rows: list[dict], summary: list[dict]) -> None:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, axes = plt.subplots(1, 4, figsize=(22, 5.5))
    ax = axes[0]
    for g, s in enumerate(summary):
        members = [r for r in rows if label(group_key(r)) == s["setting"]]
        y = [r["eval_training"] for r in members]
        jitter = np.linspace(-0.15, 0.15, len(y)) if len(y) > 1 else [0.0]
        colours = ["tab:red" if r["collapsed"] else "tab:blue" for r in members]
        ax.scatter(g + np.asarray(jitter), y, c=colours, s=18, zorder=3)
        mean, half = s["eval_training"]
        ax.errorbar(g, mean, yerr=half if np.isfinite(half) else None, fmt="_k", ms=20,
                    capsize=4, zorder=4)  # fmt: skip
    ax.axhline(common.ADVISOR_LEVEL, color="grey", ls="--", lw=1, label="advisor level")
    ax.set_ylim(-0.02, 1.02)
    ax.set_xticks(range(len(summary)), [s["setting"] for s in summary], rotation=35, ha="right",
                  fontsize=7)  # fmt: skip
    ax.set_ylabel("evaluation success, training arena")
    ax.set_title("per seed (red: below the advisor), mean ± 95 % CI")
    ax.legend(fontsize=7)
    for ax, name, title in (
        (axes[1], "_saturated", "actor heads saturated (share)"),
        (axes[2], "_critic", "critic loss / its early median (log)"),
        (axes[3], "_q", "batch-mean Q(S, A) (symlog); dashed: the return bound"),
    ):
        for r in rows:
            colour, alpha = ("tab:red", 0.9) if r["collapsed"] else ("tab:blue", 0.25)
            ax.plot(r["_episode"], r[name], color=colour, alpha=alpha, lw=1)
        ax.set_xlabel("training episode")
        ax.set_title(title)
    axes[2].set_yscale("log")
    axes[3].set_yscale("symlog", linthresh=1.0)
    for bound in sorted({r["q_bound"] for r in rows}):
        axes[3].axhline(bound, color="grey", ls="--", lw=1)
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)


def pct(x: float) -> str:
    return "–" if x is None or not np.isfinite(x) else f"{100 * x:.1f}"


def main() -> None:
    parser = argparse.ArgumentParser(
        description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter
    )
    parser.add_argument("runs", type=Path, nargs="+", help="finished run directories")
    parser.add_argument("--out", type=Path, default=Path("results"))
    parser.add_argument("--advisor-level", type=float, default=common.ADVISOR_LEVEL)
    parser.add_argument("--saturated", type=float, default=SATURATED)
    parser.add_argument("--blowup", type=float, default=BLOWUP)
    args = parser.parse_args()
    for run_dir in args.runs:
        missing = [
            f for f in ("run.json", "metrics.npz", "eval.json") if not (run_dir / f).exists()
        ]
        if missing:
            parser.error(f"{run_dir} is not a finished run directory: no {', '.join(missing)}")
    rows = [row for run_dir in args.runs for row in analyse_run(run_dir, args)]
    summary = summarise(rows)
    args.out.mkdir(parents=True, exist_ok=True)
    plot(args.out / "afp_collapse.png", rows, summary)
    public = [{k: v for k, v in r.items() if not k.startswith("_")} for r in rows]
    atomic_write_json(
        args.out / "afp_collapse.json",
        dict(analysed=common.provenance(with_jax=False), thresholds=vars(args) | {
            "runs": [str(r) for r in args.runs], "out": str(args.out)},
             groups=summary, agents=public),
    )  # fmt: skip

    def ci(pair):
        mean, half = pair
        return f"{pct(mean)} ± {pct(half)}"

    devices = sorted({f"{r['device']}" for r in rows})
    dates = sorted({(r["created"] or "")[:10] for r in rows})
    presets = sorted({r["preset"] for r in rows})
    lines = [
        "# Why seeds collapse (issue 16, item 2)",
        "",
        f"Runs: {', '.join(f'`{p.name}`' for p in args.runs)}; trained on {', '.join(devices)} "
        f"on {', '.join(dates)} (each run's `command.json` holds its command). Preset "
        f"{', '.join(f'`{p}`' for p in presets)} (the settings that differ are in each row's "
        "name), evaluation with the deterministic actor. "
        f"Collapsed: evaluation success in the training arena below {args.advisor_level:g} "
        "(the advisor's own level).",
        "",
        "## Per setting",
        "",
        *common.markdown_table(
            (
                "setting",
                "seeds",
                "eval training % (95 % CI)",
                "eval validation %",
                "worst seed %",
                "collapsed",
                f"saturated ≥ {args.saturated:g}",
                f"critic loss > {args.blowup:g}× early",
                "Q above the return bound",
            ),
            [
                (
                    s["setting"],
                    len(s["seeds"]),
                    ci(s["eval_training"]),
                    ci(s["eval_validation"]),
                    pct(s["min_seed_training"]),
                    s["collapsed"],
                    s["saturated"],
                    s["critic_blowup"],
                    s["q_over_bound"],
                )
                for s in summary
            ],
            formats=("", "d", "", "", "", "d"),
        ),  # fmt: skip
        "",
        "## Every agent that collapsed, saturated, blew up or overestimated",
        "",
        "(Saturation is listed for the Eq. 2 agents only: the DPG drives DDPG's heads to the "
        "bounds where Q is highest. A collapse starts at the first 50-episode block below "
        "25 % success after one at or above it.)",
        "",
        *common.markdown_table(
            (
                "setting",
                "seed",
                "success per 50 training episodes",
                "eval %",
                "saturated from ep.",
                "critic blow-up from ep.",
                "max Eq. 2 step (before clipping)",
                "Q above the bound from ep.",
                "largest batch-mean Q",
                "collapse from ep.",
            ),
            [
                (
                    label(group_key(r)),
                    r["seed"],
                    " ".join(f"{100 * b:.0f}" for b in r["blocks"]),
                    pct(r["eval_training"]),
                    r["saturation_at"] if r["saturation_at"] is not None else "–",
                    r["critic_blowup_at"] if r["critic_blowup_at"] is not None else "–",
                    f"{r['max_step']:.2f}" if r["max_step"] is not None else "–",
                    r["q_over_bound_at"] if r["q_over_bound_at"] is not None else "–",
                    f"{r['max_q']:.1f}" if r["max_q"] is not None else "–",
                    r["collapse_at"] if r["collapse_at"] is not None else "–",
                )
                for r in rows
                if r["collapsed"]
                or (r["saturation_at"] is not None and uses_eq2(r["agent"]))
                or r["critic_blowup_at"] is not None
                or r["q_over_bound_at"] is not None
            ],
            formats=("", "d", ""),
        ),  # fmt: skip
        "",
        "![per-seed success and diagnostics](afp_collapse.png)",
        "",
        f"Command: `{common.command_line('experiments/afp_collapse.py', sys.argv[1:])}`",
        "",
    ]
    common.write_markdown(args.out / "afp_collapse.md", lines)


if __name__ == "__main__":
    main()
