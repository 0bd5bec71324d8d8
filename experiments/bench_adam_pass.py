"""Adam's pass over one held bf16 critic matrix, against a pass that moves the same bytes.

A GPU's bf16 learner holds its critics' hidden matrices in bf16 (``agent/held_critics.py``)
and updates each with one pass (``agent/adam.py``): it reads the gradient, m, v and the matrix
(bf16 each) and writes m, v and the matrix, 14 bytes per entry, with the stochastic rounding's
integer hashes, a square root and two divisions per entry on the way. Is that pass at the
memory's bandwidth or at the arithmetic's? Timed here, vmapped over agents as training runs
it, in one process:

* ``adam``: ``adam.adam(lr, bf16, nu_bf16=True).update`` and ``adam.apply_updates``, the
  functions training calls, on a random gradient;
* ``adam + norm rows``: the same with ``held_critics._sum_of_squares``' row sums, which
  training takes in the same pass for ``grad_norm/critic``;

against the bandwidth of a device-to-device copy of as many bytes
(``measure.copy_ceiling``), measured in the same process.

    python experiments/bench_adam_pass.py --agents 64 128            # on the GPU
    python experiments/bench_adam_pass.py --agents 2 --shape 64 32 --out /tmp   # CPU smoke run

The structure mask and the tied rows' difference (``held_critics.gradient``) are left out:
they read a few rows more. Writes ``--out``/``bench_adam_pass.json`` and ``.md``.
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

import jax
import jax.numpy as jnp
import numpy as np

from advisor_jax.agent import adam, held_critics
from advisor_jax.bench import measure, writing
from advisor_jax.fileio import atomic_write_json

ARRAYS_MOVED = 7
"""bf16 arrays a pass reads or writes: gradient, m, v, matrix in; m, v, matrix out."""


def operands(agents: int, shape: tuple[int, int], seed: int = 0) -> tuple:
    """(gradient, Adam's state, matrix) of ``agents`` twin critics' ``shape`` matrices, bf16,
    in the ranges training has (gradients 1e-3, weights 0.03, v near g²)."""
    keys = jax.random.split(jax.random.key(seed), 4)
    full = (agents, 2, *shape)
    draw = lambda k, scale: (jax.random.normal(k, full) * scale).astype(jnp.bfloat16)  # noqa: E731
    grad, mu, matrix = draw(keys[0], 1e-3), draw(keys[1], 1e-3), draw(keys[3], 0.03)
    nu = jnp.abs(draw(keys[2], 1e-6))
    count = jnp.full((agents,), 7, jnp.int32)
    return grad, (count, mu, nu), matrix


def passes(lr: float = 1e-3) -> dict:
    """The two passes (module docstring), each ``(grad, state, matrix) -> outputs`` for one
    agent, to be vmapped."""
    optimizer = adam.adam(lr, mu_dtype=jnp.bfloat16, nu_bf16=True)

    def update(grad, state, matrix):
        count, mu, nu = state
        opt = optimizer.init(matrix)
        opt = (opt[0]._replace(count=count, mu=mu, nu=nu), *opt[1:])
        steps, opt = optimizer.update(grad.astype(jnp.float32), opt, matrix)  # as training
        return adam.apply_updates(matrix, steps, count), opt[0].mu, opt[0].nu

    def with_rows(grad, state, matrix):
        rows = held_critics._sum_of_squares(grad.astype(jnp.float32))
        return *update(grad, state, matrix), rows

    return {"adam": update, "adam + norm rows": with_rows}


def time_pass(fn, args, repeats: int, calls: int) -> float:
    """Best µs per call of the jitted, vmapped ``fn`` over ``repeats`` rounds of ``calls``."""
    jitted = jax.jit(jax.vmap(fn))
    jax.block_until_ready(jitted(*args))

    def round_of_calls():
        out = None
        for _ in range(calls):
            out = jitted(*args)
        return out

    return 1e6 * measure.best_of(round_of_calls, repeats) / calls


def bench(agents: int, shape: tuple[int, int], repeats: int, calls: int) -> list[dict]:
    args = operands(agents, shape)
    moved = ARRAYS_MOVED * 2 * np.prod(args[0].shape)
    copy_gb_per_s = measure.copy_ceiling(int(moved), repeats) / 1e9
    rows = []
    for name, fn in passes().items():
        us = time_pass(fn, args, repeats, calls)
        rows.append(dict(agents=agents, shape=list(shape), variant=name, us=us,
                         bytes=int(moved), gb_per_s=moved / us / 1e3,
                         copy_gb_per_s=copy_gb_per_s,
                         pct_copy=100 * moved / us / 1e3 / copy_gb_per_s))  # fmt: skip
    return rows


def main(argv=None) -> list[dict]:
    parser = argparse.ArgumentParser(
        description=__doc__.split("\n\n")[0], formatter_class=argparse.RawDescriptionHelpFormatter
    )
    parser.add_argument("--agents", type=int, nargs="+", default=[64, 128])
    parser.add_argument("--shape", type=int, nargs=2, default=[1008, 504],
                        help="one critic's held matrix, rows × columns (paper: 1008 504 and "
                             "504 608)")  # fmt: skip
    parser.add_argument("--repeats", type=int, default=5)
    parser.add_argument("--calls", type=int, default=20, help="calls per timed round")
    parser.add_argument("--out", type=Path, default=Path("results"))
    args = parser.parse_args(argv)
    if min(args.agents) < 1 or min(args.shape) < 1:
        parser.error(f"--agents {args.agents} and --shape {args.shape} must be ≥ 1")
    where = measure.provenance()
    rows = []
    for n in args.agents:
        rows += bench(n, tuple(args.shape), args.repeats, args.calls)
        for r in rows[-2:]:
            print(f"{n:4d} agents {r['variant']:17s} {r['us']:9.1f} µs {r['gb_per_s']:7.0f} "
                  f"GB/s, {r['pct_copy']:.0f} % of a copy's {r['copy_gb_per_s']:.0f}")  # fmt: skip
    atomic_write_json(args.out / "bench_adam_pass.json", dict(**where, rows=rows))
    command = writing.command_line("experiments/bench_adam_pass.py", sys.argv[1:])
    table = writing.markdown_table(
        ("agents", "matrix", "pass", "µs", "GB/s", "a copy's GB/s", "% of a copy's"),
        [(r["agents"], "×".join(map(str, r["shape"])), r["variant"], r["us"], r["gb_per_s"],
          r["copy_gb_per_s"], r["pct_copy"]) for r in rows],
        formats=("", "", "", ".1f", ".0f", ".0f", ".0f"),
        align="rllr",
    )  # fmt: skip
    title = (f"Adam's pass over a held bf16 critic matrix (twin critics, vmapped), "
             f"{where['device']}, jax {where['jax']}, {where['date']}; GB/s counts "
             f"{ARRAYS_MOVED} bf16 arrays read or written.")  # fmt: skip
    writing.write_markdown(
        args.out / "bench_adam_pass.md",
        ["# Adam's pass against the bytes it moves", "", title, "", *table, "",
         f"Command: `{command}`", ""],
    )  # fmt: skip
    return rows


if __name__ == "__main__":
    main()
