"""Paper Table 1 / Fig. 8 / Fig. 9: agent types × seeds, trained and evaluated alike.

    # train (one compile per agent type; every seed of a type is one vmapped program)
    python experiments/table1.py train --runs runs/table1 --preset paper --episodes 200 --seeds 4
    # aggregate whatever is in runs/table1 into results/table1.md and .png
    python experiments/table1.py summarize --runs runs/table1 --out results

Every agent type is evaluated on the same 100 episodes per arena (same key), so the rows
are paired. Cells are mean ± half-width of the Student-t 95 % interval over seeds.
"""

from __future__ import annotations

import argparse
import dataclasses
import json
import sys
from pathlib import Path

import common
import numpy as np

from advisor_jax.agent.config import PAPER_AGENTS, preset
from advisor_jax.training.reporting import mean_ci95, moving_average, save_png

PAPER_TABLE1 = {  # success, training / validation environment (paper Table 1)
    "DDPG": (72.2, 71.3),
    "ADDPG": (78.3, 77.1),
    "ADDPG+AfD": (81.3, 79.3),
    "ADDPG+AfP": (84.5, 83.0),
    "ADDPG+AfDP": (88.1, 85.2),
    "ATD3+AfDP": (90.8, 89.4),
}


def train(args) -> None:
    from advisor_jax.training.host_loop import run_training

    for agent in args.agents:
        cfg, hp = preset(args.preset, agent)
        cfg = dataclasses.replace(cfg, episodes=args.episodes or cfg.episodes)
        out = args.runs / agent.replace("+", "_")
        run_training(
            cfg,
            hp,
            {},
            list(range(args.seed, args.seed + args.seeds)),
            out,
            eval_episodes=args.eval_episodes,
            checkpoint_every=0,
            progress=False,
            meta={"preset": args.preset},
        )


def _fmt(mean: float, half: float) -> str:
    if np.isnan(mean):
        return "–"
    return f"{mean:.1f}" + ("" if np.isnan(half) else f" ± {half:.1f}")


def summarize(args) -> None:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    runs = []
    for agent in PAPER_AGENTS + ("TD3", "ATD3"):
        run_dir = args.runs / agent.replace("+", "_")
        if (run_dir / "run.json").is_file():
            runs.append((agent, run_dir, json.loads((run_dir / "run.json").read_text())))
    if not runs:
        sys.exit(f"no runs under {args.runs}")
    first = runs[0][2]
    cfg = first["config"]
    lines = [
        "# Table 1 (simulation): success rate of each agent type",
        "",
        f"{cfg['episodes']} training episodes per agent in `{cfg['arena']}`, seeds "
        f"{[a['seed'] for a in first['agents']]}; evaluation: deterministic actor, "
        f"{first['evaluation']['training']['episodes']} episodes per arena, the same episodes "
        "for every agent. Mean ± 95 % CI over seeds (%). Device: "
        f"{first['device']}; date {first['created'][:10]}.",
    ]
    table = []
    fig, axes = plt.subplots(1, 2, figsize=(12, 4), constrained_layout=True)
    for agent, run_dir, summary in runs:
        ev = summary["evaluation"]
        cells = []
        for arena in ("training", "validation"):
            success = [100 * v for v in ev[arena]["success"] if v is not None]
            cells.append(_fmt(*mean_ci95(success)))
        speed = [v for v in ev["training"]["collision_speed"] if v is not None]
        paper = PAPER_TABLE1.get(agent)
        paper_cell = f"{paper[0]:.1f} / {paper[1]:.1f}" if paper else "–"
        speed_cell = _fmt(*mean_ci95(speed)) if speed else "–"
        table.append((agent, len(summary["agents"]), *cells, speed_cell, paper_cell))
        metrics = np.load(run_dir / "metrics.npz")
        episodes = np.arange(1, metrics["outcome"].shape[1] + 1)
        window = max(1, min(150, len(episodes) // 5))
        for ax, values in zip(
            axes, (metrics["reward_per_step"], metrics["collision_speed"]), strict=True
        ):
            curves = moving_average(values.astype(np.float64), window)
            mean, std = np.nanmean(curves, axis=0), np.nanstd(curves, axis=0)
            (line,) = ax.plot(episodes, mean, label=agent)
            ax.fill_between(episodes, mean - std, mean + std, color=line.get_color(), alpha=0.15)
    axes[0].set_title(f"reward per step (moving average, w={window}; Fig. 8)")
    axes[1].set_title(f"collision speed, m/s (moving average, w={window}; Fig. 9)")
    for ax in axes:
        ax.set_xlabel("episode")
        ax.grid(alpha=0.3)
    axes[0].legend(fontsize=8)
    save_png(fig, args.out / "table1.png")
    train_argv = ["train", "--runs", args.runs, "--preset", first.get("preset", "paper"),
                  "--episodes", cfg["episodes"], "--seeds", len(first["agents"])]  # fmt: skip
    summarize_argv = ["summarize", "--runs", args.runs, "--out", args.out]
    lines += [
        "",
        *common.markdown_table(
            ("agent", "seeds", "training env", "validation env", "collision speed, eval (m/s)",
             "paper (train / val)"),
            table,
        ),
        "",
        "![learning curves](table1.png)",
        "",
        f"Commands: `{common.command_line('experiments/table1.py', train_argv)}` then "
        f"`{common.command_line('experiments/table1.py', summarize_argv)}`.",
    ]  # fmt: skip
    common.write_markdown(args.out / "table1.md", lines, echo=True)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    sub = parser.add_subparsers(dest="command", required=True)
    t = sub.add_parser("train")
    t.add_argument("--runs", type=Path, default=Path("runs/table1"))
    t.add_argument("--preset", default="paper")
    t.add_argument("--agents", nargs="+", default=list(PAPER_AGENTS))
    t.add_argument("--episodes", type=int, default=0, help="N_total (0 = the preset's)")
    t.add_argument("--seeds", type=int, default=6)
    t.add_argument("--seed", type=int, default=0)
    t.add_argument("--eval-episodes", type=int, default=100)
    s = sub.add_parser("summarize")
    s.add_argument("--runs", type=Path, default=Path("runs/table1"))
    s.add_argument("--out", type=Path, default=Path("results"))
    args = parser.parse_args()
    train(args) if args.command == "train" else summarize(args)


if __name__ == "__main__":
    main()
