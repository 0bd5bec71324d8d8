"""Closed-loop check of an exported policy: numpy runner in the loop vs JAX evaluation.

    python experiments/closed_loop.py POLICY_DIR [--episodes 100] [--seed 0]

Drives the simulated ``physical`` arena from RPLIDAR-format scans and tracked poses through
the car runner's watchdog controller (``advisor_jax/closed_loop.py``) and compares its
success rate with the JAX evaluation of the same weights on the same episodes. Writes
``results/closed_loop.md`` and ``results/closed_loop.json``.
"""

from __future__ import annotations

import argparse
import datetime
import platform
import time
from pathlib import Path

import jax
import numpy as np

import envs
from advisor_jax.closed_loop import binomial_ci95, run_closed_loop
from advisor_jax.fileio import atomic_write_json, atomic_write_text
from advisor_jax.runner.policy import load_policy


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("policy", type=Path, help="export directory (advisor-jax export)")
    parser.add_argument("--episodes", type=int, default=100)
    parser.add_argument("--seed", type=int, default=0)
    parser.add_argument("--out", type=Path, default=Path("results"))
    args = parser.parse_args()
    policy = load_policy(args.policy)
    t0 = time.perf_counter()
    r = run_closed_loop(policy, args.episodes, jax.random.PRNGKey(args.seed))
    seconds = time.perf_counter() - t0
    names = envs.OUTCOME_NAMES
    rows = {
        "runner": {n: float(np.mean(r.runner_outcomes == i)) for i, n in enumerate(names) if i},
        "jax": {n: float(np.mean(r.jax_outcomes == i)) for i, n in enumerate(names) if i},
    }
    result = dict(
        date=datetime.date.today().isoformat(), host=platform.node(), policy=str(args.policy),
        agent=policy.meta["config"].get("agent"), arena=policy.env["arena"],
        episodes=args.episodes, seed=args.seed, seconds=round(seconds, 1), stops=r.stops,
        agreement=r.agreement, rates=rows,
    )  # fmt: skip
    atomic_write_json(args.out / "closed_loop.json", result)
    ci = binomial_ci95(r.jax_success, args.episodes)
    lines = [
        "# Closed loop: numpy car runner vs JAX actor",
        "",
        f"Policy `{args.policy}` ({result['agent']}), arena `{result['arena']}`, "
        f"{args.episodes} episodes (seed {args.seed}), {result['date']}, "
        f"CPU ({platform.machine()}).",
        "The runner sees RPLIDAR-format scans (clockwise degrees, mm) made from the 200 simulated",
        "beams and the tracked pose; it builds the observation, runs the numpy MLP and commands",
        "(V, ω) through its watchdog controller. Same episodes (starts, goals) for both rows.",
        "",
        "| driver | success | collision | timeout |",
        "|---|---:|---:|---:|",
    ]
    for who, label in (("runner", "numpy runner in the loop"), ("jax", "JAX evaluation")):
        x = rows[who]
        lines.append(
            f"| {label} | {100 * x['goal']:.1f} % | {100 * x['collision']:.1f} % | "
            f"{100 * x['timeout']:.1f} % |"
        )
    lines += [
        "",
        f"Same outcome in {100 * r.agreement:.1f} % of the episodes; watchdog stops: {r.stops}. "
        f"Sampling half-width of the success rate (95 %): ±{100 * ci:.1f} points.",
        "",
        f"Command: `python experiments/closed_loop.py {args.policy} --episodes {args.episodes} "
        f"--seed {args.seed}`",
        "",
    ]
    atomic_write_text(args.out / "closed_loop.md", "\n".join(lines))
    print("\n".join(lines))


if __name__ == "__main__":
    main()
