"""Wall time of brax's SAC and PPO against advisor-jax's agents, same arena, budget and seeds.

    python experiments/bench_brax_baselines.py [--preset quick] [--seeds 3] [--episodes 60]
        [--agents DDPG ATD3+AfDP brax-SAC brax-PPO] [--runs runs/brax_bench]
        [--out results/brax_baselines_cpu]

Runs ``advisor-jax train --agent A --preset P --seeds N --episodes E --eval-seed 0`` for each
agent type, one after another on this machine, and times the whole command (start-up and
compiles included; advisor-jax trains the seeds as one vmapped population, brax one seed
per call) and the training alone (run.json ``train_seconds``). Also records each type's env
steps per agent, completed episodes and evaluation success, so the rows are comparable and
the run directories (``--runs``) go straight into ``advisor-jax report``. Writes
``OUT.md`` and ``OUT.json``.
"""

from __future__ import annotations

import argparse
import json
import os
import subprocess
import sys
import time
from pathlib import Path

import numpy as np

from advisor_jax.bench import measure, writing
from advisor_jax.fileio import atomic_write_json


def train(agent: str, args, out: Path) -> dict:
    """One ``advisor-jax train`` of ``agent``; its wall time and run.json's record."""
    command = [
        "advisor-jax", "train", "--agent", agent, "--preset", args.preset,
        "--seeds", str(args.seeds), "--eval-seed", "0",
        "--eval-episodes", str(args.eval_episodes), "--out", str(out), "--no-progress",
    ]  # fmt: skip
    if args.episodes:
        command += ["--episodes", str(args.episodes)]
    started = time.perf_counter()
    subprocess.run(command, check=True)
    wall = time.perf_counter() - started
    run = json.loads((out / "run.json").read_text())
    evaluation = run["evaluation"]
    return {
        "agent": agent,
        "command": " ".join(command),
        "wall_seconds": round(wall, 1),
        "train_seconds": run["train_seconds"],
        "seconds_per_agent": run.get("seconds_per_agent"),
        "env_steps_per_agent": run["env_steps_per_agent"],
        "episodes_completed": run["episodes_completed"],
        "success": {a: float(np.mean(ev["success"])) for a, ev in evaluation.items()},
    }


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--preset", default="quick")
    parser.add_argument("--seeds", type=int, default=3)
    parser.add_argument("--episodes", type=int, default=0, help="0: the preset's N_total")
    parser.add_argument("--eval-episodes", type=int, default=50)
    parser.add_argument("--agents", nargs="+",
                        default=["DDPG", "ATD3+AfDP", "brax-SAC", "brax-PPO"])  # fmt: skip
    parser.add_argument("--runs", type=Path, default=Path("runs/brax_bench"))
    parser.add_argument("--out", type=Path, default=Path("results/brax_baselines_cpu"))
    args = parser.parse_args()
    load_before = os.getloadavg()[0]  # the machine may be shared: say how busy it was
    rows = [train(a, args, args.runs / a.replace("+", "_").lower()) for a in args.agents]
    load = [round(load_before, 1), round(os.getloadavg()[0], 1)]
    result = {**measure.provenance(), "preset": args.preset, "seeds": args.seeds,
              "load_average_1min": load, "rows": rows}  # fmt: skip
    atomic_write_json(args.out.with_suffix(".json"), result)
    table = writing.markdown_table(
        ("agent", "wall time (s)", "training (s)", "per seed (s)", "env steps / agent",
         "episodes / agent", "eval success, training arena"),
        [(r["agent"], f"{r['wall_seconds']:,.0f}", f"{r['train_seconds']:,.0f}",
          f"{r['train_seconds'] / args.seeds:,.0f}",
          f"{np.mean(r['env_steps_per_agent']):,.0f}",
          f"{np.mean(r['episodes_completed']):.0f}",
          f"{100 * r['success'].get('training', float('nan')):.0f} %") for r in rows],
    )  # fmt: skip
    command = writing.command_line("experiments/bench_brax_baselines.py", sys.argv[1:])
    lines = [
        f"# brax SAC / PPO against advisor-jax's agents: wall time ({result['backend']})",
        "",
        f"{result['date']}, {result['device']} ({result['cpu']}, {result['cpu_count']} cores), "
        f"jax {result['jax']}, load average {load[0]} before and {load[1]} after; preset "
        f"`{args.preset}`, {args.seeds} seeds per type, every "
        "type under the same episode budget and scored on the same evaluation episodes "
        f"({args.eval_episodes} per arena, eval seed 0).",
        "",
        "Wall time: the whole `advisor-jax train` command (start-up, compiles, training, "
        "evaluation, files); training: run.json's `train_seconds` (advisor-jax: the "
        "population's training loop, its compile included; brax: every seed's call of "
        "brax's trainer, its compiles included). advisor-jax trains all seeds as "
        "one vmapped program; brax trains one seed per call, one after another.",
        "",
        *table,
        "",
        f"Command: `{command}`",
    ]
    writing.write_markdown(args.out.with_suffix(".md"), lines, echo=True)


if __name__ == "__main__":
    main()
