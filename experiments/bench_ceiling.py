"""The matmul ceiling two ways, interleaved in one process: ``measure.matmul_ceiling`` with one
product per timed call (as every learner report took it until 2026-11-28) and with its chain
of dependent products per call (since). The GPU's SM clock, power and throttle reasons are read
after each.

    python experiments/bench_ceiling.py --out ceiling.json     # on the GPU; run it in several
                                                               # processes: the first varied

Writes ``--out`` (a JSON list, one row per dtype and round) and prints each row.
``results/bench_ceiling/`` has three processes' files and what they showed.
"""

from __future__ import annotations

import argparse
import json
import subprocess

import jax.numpy as jnp

from advisor_jax.bench import measure

GPU_STATE = "clocks.sm,clocks.mem,power.draw,temperature.gpu,clocks_throttle_reasons.active"


def gpu_state() -> str:
    """nvidia-smi's reading of ``GPU_STATE`` (or why there is none)."""
    try:
        query = ["nvidia-smi", f"--query-gpu={GPU_STATE}", "--format=csv,noheader"]
        return subprocess.run(query, capture_output=True, text=True).stdout.strip()
    except OSError as e:
        return str(e)


def chain_magnitude(n: int, dtype: str, chain: int) -> float:
    """Mean |entry| after ``measure.matmul_ceiling``'s chain: neither overflowed nor vanished."""
    out = measure.chained_matmuls(*measure.chain_operands(n, dtype), chain)
    return float(jnp.abs(out.astype(jnp.float32)).mean())


def main(argv=None) -> list[dict]:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--size", type=int, default=8192)
    parser.add_argument("--chain", type=int, default=measure.CHAIN)
    parser.add_argument("--rounds", type=int, default=4)
    parser.add_argument("--out", required=True)
    args = parser.parse_args(argv)
    rows = []
    for dtype in ("bfloat16", "float32"):
        for r in range(args.rounds):
            single = measure.matmul_ceiling(args.size, dtype=dtype, chain=1) / 1e12
            after_single = gpu_state()
            chained = measure.matmul_ceiling(args.size, dtype=dtype, chain=args.chain) / 1e12
            magnitude = chain_magnitude(args.size, dtype, args.chain)
            row = dict(dtype=dtype, round=r, one_product=single, chained=chained, mag=magnitude)
            rows.append(dict(row, smi_after_single=after_single, smi_after_loop=gpu_state()))
            print(json.dumps(rows[-1]), flush=True)
    with open(args.out, "w") as f:
        json.dump(rows, f, indent=1)
    return rows


if __name__ == "__main__":
    main()
