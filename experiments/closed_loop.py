"""Closed-loop check of an exported policy: numpy runner in the loop vs JAX evaluation.

    python experiments/closed_loop.py POLICY_DIR [--episodes 100] [--seed 0]

Drives the simulated ``physical`` arena from RPLIDAR-format scans and tracked poses through
the car runner's watchdog controller (``advisor_jax/evaluation/closed_loop.py``) and compares its
success rate with the JAX evaluation of the same weights on the same episodes. Writes
``results/closed_loop.md`` and ``results/closed_loop.json``.
"""

from __future__ import annotations

import argparse
import platform
import sys
from pathlib import Path

import jax
import numpy as np

import envs
from advisor_jax.bench import measure, writing
from advisor_jax.evaluation.closed_loop import binomial_ci95, run_closed_loop
from advisor_jax.fileio import atomic_write_json
from advisor_jax.runner.errors import RunnerError
from advisor_jax.runner.policy import load_policy


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("policy", type=Path, help="export directory (advisor-jax export)")
    parser.add_argument("--episodes", type=int, default=100)
    parser.add_argument("--seed", type=int, default=0)
    parser.add_argument("--out", type=Path, default=Path("results"))
    args = parser.parse_args()
    try:
        policy = load_policy(args.policy)
        key = jax.random.PRNGKey(args.seed)
        r, seconds = measure.run_timed(lambda: run_closed_loop(policy, args.episodes, key))
    except (ValueError, OSError, RunnerError) as e:  # a wrong export: one line, no traceback
        sys.exit(f"closed_loop.py: error: {e}")
    names = envs.OUTCOME_NAMES
    rows = {
        "runner": {n: float(np.mean(r.runner_outcomes == i)) for i, n in enumerate(names) if i},
        "jax": {n: float(np.mean(r.jax_outcomes == i)) for i, n in enumerate(names) if i},
    }
    result = dict(
        **measure.provenance(), policy=str(args.policy),
        agent=policy.meta["config"].get("agent"), arena=policy.env["arena"],
        episodes=args.episodes, seed=args.seed, seconds=round(seconds, 1), stops=r.stops,
        agreement=r.agreement, rates=rows,
    )  # fmt: skip
    atomic_write_json(args.out / "closed_loop.json", result)
    ci = binomial_ci95(r.jax_success, args.episodes)
    options = ["--episodes", args.episodes, "--seed", args.seed]
    command = writing.command_line("experiments/closed_loop.py", [args.policy, *options])
    drivers = (("numpy runner in the loop", rows["runner"]), ("JAX evaluation", rows["jax"]))
    table = writing.markdown_table(
        ("driver", "success", "collision", "timeout"),
        [(label, *(f"{100 * x[n]:.1f} %" for n in ("goal", "collision", "timeout")))
         for label, x in drivers],
    )  # fmt: skip
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
        *table,
        "",
        f"Same outcome in {100 * r.agreement:.1f} % of the episodes; watchdog stops: {r.stops}. "
        f"Sampling half-width of the success rate (95 %): ±{100 * ci:.1f} points.",
        "",
        f"Command: `{command}`",
    ]
    writing.write_markdown(args.out / "closed_loop.md", lines, echo=True)


if __name__ == "__main__":
    main()
