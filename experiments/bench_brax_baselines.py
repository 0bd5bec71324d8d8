"""Wall time of brax's SAC and PPO against advisor-jax's agents, same arena, budget and seeds.

    python experiments/bench_brax_baselines.py [--preset quick] [--seeds 3] [--episodes 60]
        [--agents DDPG ATD3+AfDP brax-SAC brax-PPO] [--runs runs/brax_bench]
        [--out results/brax_baselines_cpu] [--brax-cpus 16-63]

Runs ``advisor-jax train --agent A --preset P --seeds N --episodes E --eval-seed 0`` for each
agent type, one after another on this machine, and times the whole command (start-up and
compiles included; advisor-jax trains the seeds as one vmapped population, brax one seed
per call) and the training alone (run.json ``train_seconds``). Also records each type's env
steps per agent, completed episodes and evaluation success, so the rows are comparable and
the run directories (``--runs``) go straight into ``advisor-jax report``. Writes
``OUT.md`` and ``OUT.json``.

``--brax-cpus FIRST-LAST`` trains every brax seed as its own one-seed process
(``--seed k --seeds 1``) on the CPU instead, all of them at once, each pinned to its share
of those cores: brax's trainer cannot be vmapped over seeds, so on a many-core host this
is how its 16 seeds run side by side (the report pools one-seed runs by their settings).
The other agent types still train as one population on the default device, while the brax
processes run.
"""

from __future__ import annotations

import argparse
import dataclasses
import json
import os
import subprocess
import sys
import time
from pathlib import Path

import numpy as np

from advisor_jax.bench import measure, writing
from advisor_jax.fileio import atomic_write_json


def train_command(agent: str, args, out: Path | str, seeds: int, seed: str | None) -> list[str]:
    """``advisor-jax train`` of ``seeds`` seeds of ``agent`` (from ``seed``, if given)."""
    command = [
        "advisor-jax", "train", "--agent", agent, "--preset", args.preset,
        "--seeds", str(seeds), *(["--seed", seed] if seed is not None else []),
        "--eval-seed", "0", "--eval-episodes", str(args.eval_episodes),
        "--out", str(out), "--no-progress",
    ]  # fmt: skip
    return command + (["--episodes", str(args.episodes)] if args.episodes else [])


def train(agent: str, args, out: Path) -> dict:
    """One ``advisor-jax train`` of ``agent``; its wall time and run.json's record."""
    command = train_command(agent, args, out, args.seeds, str(args.seed0) if args.seed0 else None)
    started = time.perf_counter()
    subprocess.run(command, check=True)
    wall = time.perf_counter() - started
    run = json.loads((out / "run.json").read_text())
    evaluation = run["evaluation"]
    return {
        "agent": agent,
        "command": " ".join(command),
        "where": f"{measure.provenance()['device']}, one population",
        "wall_seconds": round(wall, 1),
        "train_seconds": run["train_seconds"],
        "seconds_per_agent": run.get("seconds_per_agent"),
        "env_steps_per_agent": run["env_steps_per_agent"],
        "episodes_completed": run["episodes_completed"],
        "success": {a: float(np.mean(ev["success"])) for a, ev in evaluation.items()},
    }


def cpu_range(text: str) -> list[int]:
    """``16-63`` (or ``5``) as the list of core numbers, refused when this machine lacks one."""
    first, _, last = text.partition("-")
    cores = list(range(int(first), int(last or first) + 1))
    missing = sorted(set(cores) - os.sched_getaffinity(0))
    if not cores or missing:
        raise argparse.ArgumentTypeError(
            f"--brax-cpus {text}: this machine has no core(s) {missing[:8]} to run on"
        )
    return cores


@dataclasses.dataclass
class BraxSeed:
    """One brax seed training as its own process on the CPU."""

    agent: str
    seed: int
    cores: int  # how many it is pinned to
    out: Path
    process: subprocess.Popen
    started: float  # time.perf_counter()
    seconds: float | None = None  # its wall time, once it has ended


def start_seed(agent: str, seed: int, cores: list[int], args, out: Path) -> BraxSeed:
    """One brax seed as its own process on the CPU, pinned to ``cores``."""
    out.mkdir(parents=True, exist_ok=True)
    with open(out.parent / f"{out.name}.log", "w") as log:  # the child keeps its own copy
        process = subprocess.Popen(
            train_command(agent, args, out, 1, str(seed)), stdout=log, stderr=subprocess.STDOUT,
            env={**os.environ, "JAX_PLATFORMS": "cpu"},
            preexec_fn=lambda: os.sched_setaffinity(0, cores),
        )  # fmt: skip
    return BraxSeed(agent, seed, len(cores), out, process, time.perf_counter())


def brax_on_cpus(agents: list[str], args) -> list[BraxSeed]:
    """Start every seed of every brax type in ``agents`` (cores split evenly, SAC's first);
    ``finish_brax`` waits for them."""
    jobs = [(a, args.seed0 + k) for a in agents for k in range(args.seeds)]
    if len(args.brax_cpus) < len(jobs):
        raise SystemExit(
            f"--brax-cpus: {len(args.brax_cpus)} cores for {len(jobs)} brax seeds; give at "
            "least one core per seed"
        )
    shares = np.array_split(np.array(args.brax_cpus), len(jobs))
    return [
        start_seed(agent, seed, [int(c) for c in cores], args,
                   args.runs / agent.replace("+", "_").lower() / f"seed{seed:02d}")
        for (agent, seed), cores in zip(jobs, shares, strict=True)
    ]  # fmt: skip


def finish_brax(started: list[BraxSeed], args) -> list[dict]:
    """Wait for the brax processes; one row per type (wall time: from the first start to the
    last seed done; training: the sum of the seeds' ``train_seconds``)."""
    while any(s.seconds is None for s in started):  # polled: each seed's end time its own
        for s in started:
            if s.seconds is not None or s.process.poll() is None:
                continue
            if s.process.returncode != 0:
                raise SystemExit(f"{s.agent} seed {s.seed} failed: see {s.out}.log")
            s.seconds = time.perf_counter() - s.started
        time.sleep(1.0)
    rows = []
    for agent in dict.fromkeys(s.agent for s in started):
        mine = [s for s in started if s.agent == agent]
        runs = [json.loads((s.out / "run.json").read_text()) for s in mine]
        rows.append({
            "agent": agent,
            "command": " ".join(train_command(agent, args, mine[0].out.parent / "seedK", 1, "K")),
            "where": f"CPU, {len(mine)} one-seed processes, {mine[0].cores} core(s) each",
            "wall_seconds": round(max(s.seconds for s in mine), 1),
            "train_seconds": round(sum(r["train_seconds"] for r in runs), 1),
            "seconds_per_agent": round(float(np.mean([r["train_seconds"] for r in runs])), 1),
            "env_steps_per_agent": [n for r in runs for n in r["env_steps_per_agent"]],
            "episodes_completed": [e for r in runs for e in r["episodes_completed"]],
            "success": {
                arena: float(np.mean([r["evaluation"][arena]["success"] for r in runs]))
                for arena in runs[0]["evaluation"]
            },
        })  # fmt: skip
    return rows


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
    parser.add_argument("--brax-cpus", type=cpu_range, default=None, metavar="FIRST-LAST",
                        help="train each brax seed as its own process on these CPU cores, "
                        "all at once (default: one after another in one process)")  # fmt: skip
    parser.add_argument("--seed", dest="seed0", type=int, default=0, help="first seed")
    args = parser.parse_args()
    load_before = os.getloadavg()[0]  # the machine may be shared: say how busy it was
    on_cpus = [a for a in args.agents if a.startswith("brax-")] if args.brax_cpus else []
    started = brax_on_cpus(on_cpus, args) if on_cpus else []
    rows = [
        train(a, args, args.runs / a.replace("+", "_").lower())
        for a in args.agents
        if a not in on_cpus
    ]
    rows += finish_brax(started, args) if started else []
    load = [round(load_before, 1), round(os.getloadavg()[0], 1)]
    result = {**measure.provenance(), "preset": args.preset, "seeds": args.seeds,
              "load_average_1min": load, "rows": rows}  # fmt: skip
    atomic_write_json(args.out.with_suffix(".json"), result)
    table = writing.markdown_table(
        ("agent", "where", "wall time (s)", "training (s)", "per seed (s)",
         "env steps / agent", "episodes / agent", "eval success, training arena"),
        [(r["agent"], r["where"], f"{r['wall_seconds']:,.0f}", f"{r['train_seconds']:,.0f}",
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
        "one vmapped program; brax trains one seed per call, one after another, or (where the "
        "table says so) each seed as its own process on the CPU, all at once: their wall time runs "
        "from the start to the last seed done, beside the population's.",
        *[f"\n{r['agent']}, each seed: `{r['command']}`" for r in rows if "CPU," in r["where"]],
        "",
        *table,
        "",
        f"Command: `{command}`",
    ]
    writing.write_markdown(args.out.with_suffix(".md"), lines, echo=True)


if __name__ == "__main__":
    main()
