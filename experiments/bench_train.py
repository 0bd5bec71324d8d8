"""Training throughput: agent environment steps per second of the full jitted chunk.

One environment step of an agent = advisor + actor + Eq. 1 selector (2 critic calls) + OU
noise + MJX env step + replay insert + `updates_per_step` updates (critic every step, actor
every d-th). ``bench_learner.py`` times the updates alone; the gap between the two is the
cost of data collection and bookkeeping.

    python experiments/bench_train.py --preset paper --agents 8 32 64
    python experiments/bench_train.py --preset quick --agents 1 4 --chunk 100   # CPU

Writes ``results/bench_train.md`` / ``.json``. A warm-up chunk (compile + the first steps,
before the buffer holds a batch) is excluded from the timing.
"""

from __future__ import annotations

import argparse
import dataclasses
import datetime
import platform
import sys
import time
from pathlib import Path

import jax
import jax.numpy as jnp

from advisor_jax.config import preset
from advisor_jax.fileio import atomic_write_json, atomic_write_text
from advisor_jax.run import population_functions
from advisor_jax.sweep import agent_keys, build_population


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--preset", default="paper")
    parser.add_argument("--agent", default="ATD3+AfDP")
    parser.add_argument("--agents", type=int, nargs="+", default=[8, 32, 64])
    parser.add_argument("--chunk", type=int, default=500, help="env steps per jitted call")
    parser.add_argument("--repeats", type=int, default=3)
    parser.add_argument("--out", type=Path, default=Path("results"))
    args = parser.parse_args()

    device = jax.devices()[0]
    print(f"device: {device.device_kind} ({jax.default_backend()}), jax {jax.__version__}")
    rows = []
    for n in args.agents:
        cfg, hp = preset(args.preset, args.agent)
        # Enough episodes that nobody finishes during the benchmark; warm-up past learning start.
        cfg = dataclasses.replace(cfg, chunk_steps=args.chunk, episodes=100_000)
        _, init_fn, chunk_fn = population_functions(cfg)
        hp, _ = build_population(hp, {}, seeds=list(range(n)))
        state = init_fn(agent_keys(list(range(n))))
        t0 = time.perf_counter()
        step = 0
        while step * cfg.envs_per_agent < cfg.agent.warmup + args.chunk:
            state, _ = chunk_fn(state, hp, jnp.int32(step))
            step += args.chunk
        jax.block_until_ready(state)
        warmup = time.perf_counter() - t0
        best = float("inf")
        for _ in range(args.repeats):
            t = time.perf_counter()
            state, _ = chunk_fn(state, hp, jnp.int32(step))
            jax.block_until_ready(state)
            best = min(best, time.perf_counter() - t)
            step += args.chunk
        sps = n * args.chunk * cfg.envs_per_agent / best
        rows.append(dict(agents=n, agent_steps_per_s=sps, seconds_per_chunk=best, warmup_s=warmup))
        print(f"agents {n:4d}: {sps:10.0f} agent env-steps/s, warm-up {warmup:.1f} s")

    result = dict(
        date=datetime.date.today().isoformat(), device=device.device_kind,
        backend=jax.default_backend(), host=platform.node(), jax=jax.__version__,
        preset=args.preset, agent=args.agent, chunk=args.chunk, rows=rows,
    )  # fmt: skip
    atomic_write_json(args.out / "bench_train.json", result)
    lines = [
        "# Training throughput (full step: env + advisor + selector + update)",
        "",
        f"{args.agent}, preset `{args.preset}`, {args.chunk} env steps per jitted chunk; "
        f"{device.device_kind} ({jax.default_backend()}), jax {jax.__version__}, {result['date']}.",
        "",
        "| agents | agent env-steps/s | s per chunk |",
        "|---:|---:|---:|",
        *[
            f"| {r['agents']} | {r['agent_steps_per_s']:,.0f} | {r['seconds_per_chunk']:.3f} |"
            for r in rows
        ],
        "",
        f"Command: `python experiments/bench_train.py {' '.join(sys.argv[1:])}`",
        "",
    ]
    atomic_write_text(args.out / "bench_train.md", "\n".join(lines))


if __name__ == "__main__":
    main()
