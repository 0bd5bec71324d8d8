"""What XLA made of the learner's GEMMs: library calls, their epilogues, and the fusions left.

Compiles the update loop that training runs (``bench.learner_loop.make_update_loop``, four
updates, two agents, paper sizes, ATD3+AfDP) for each precision and counts, in the optimized
HLO, the GEMM library calls by target (``__cublas$lt$matmul`` on GPUs), their epilogues
(``RELU``: the hidden layer's ReLU applied by the GEMM, ``agent/gemm_layers.py``;
``DEFAULT``: none) and the fusions (XLA's own kernels). On a CPU the GEMMs stay ``dot``s and
there are no epilogues.

    python experiments/gemm_epilogues.py                  # on the GPU
    python experiments/gemm_epilogues.py --out DIR        # also the HLO text per precision

Prints one line per precision (and writes ``gemm_epilogues.json`` with ``--out``).
"""

from __future__ import annotations

import argparse
import collections
import dataclasses
import re
import sys
from pathlib import Path

import jax

from advisor_jax.agent.config import parse_agent
from advisor_jax.bench import measure
from advisor_jax.bench.learner_loop import SMALL, fill_replay, make_update_loop
from advisor_jax.fileio import atomic_write_json


def count(hlo: str) -> dict:
    """Library GEMMs by target, their epilogues, fusions and plain dots of an HLO text."""
    return dict(
        library_calls=dict(collections.Counter(re.findall(r'custom_call_target="([^"]+)"', hlo))),
        epilogues=dict(collections.Counter(re.findall(r'"epilogue":"([A-Z_]+)"', hlo))),
        fusions=len(re.findall(r"^\s*\S+ = \S+ fusion\(", hlo, re.M)),
        dots=len(re.findall(r"^\s*\S+ = \S+ dot\(", hlo, re.M)),
    )


def compiled_loop(precision: str, small: bool = False) -> str:
    """The optimized HLO of four updates of two ``precision`` agents."""
    cfg = dataclasses.replace(
        parse_agent("ATD3+AfDP", **(SMALL if small else {})), precision=precision
    )
    learner, loop = make_update_loop(cfg, 4)
    keys = jax.random.split(jax.random.key(0), 2)
    states = jax.jit(jax.vmap(learner.init))(keys)
    fill = jax.jit(jax.vmap(fill_replay, in_axes=(None, 0)), static_argnums=0)
    return loop.lower(states, fill(cfg.buffer_size, keys), keys).compile().as_text()


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--precision", nargs="+", default=["bf16", "fp32"])
    parser.add_argument("--small", action="store_true", help="tiny networks (CPU smoke run)")
    parser.add_argument("--out", type=Path, default=None)
    args = parser.parse_args(argv)
    rows = {}
    for precision in args.precision:
        hlo = compiled_loop(precision, args.small)
        rows[precision] = count(hlo)
        print(precision, rows[precision], flush=True)
        if args.out is not None:
            args.out.mkdir(parents=True, exist_ok=True)
            (args.out / f"hlo_{precision}.txt").write_text(hlo)
    if args.out is not None:
        atomic_write_json(args.out / "gemm_epilogues.json", dict(**measure.provenance(), rows=rows))
    return 0


if __name__ == "__main__":
    sys.exit(main())
