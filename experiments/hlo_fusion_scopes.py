"""Kernels of the compiled training chunk that join its collection and its update, and the
replay-buffer copies in its loops (``advisor_jax.bench.hlo_scopes``).

Compiles (does not run) the population chunk as training builds it (``program.
population_functions``: the program, layout and XLA options training picks) on the default
platform, or reads a saved optimized HLO text (``--hlo``, plain or gzip), and prints for each
loop body: its kernels, the fusions holding ops of both the collection's forward passes and
an update step (each such kernel makes the two halves of a step wait for each other), and the
copies of arrays of at least ``--min-copy-kib``; with ``--list`` also the joining fusions and
the longest chain of data dependence as runs of one half of a step (a collection run before a
draw or an update: that update waits for the collection). GPU and CPU compiles differ; a GPU answer
needs a GPU:

    python experiments/hlo_fusion_scopes.py --preset paper --agents 1 --precision bf16
    python experiments/hlo_fusion_scopes.py --hlo chunk.hlo.gz --list
"""

from __future__ import annotations

import argparse
import gzip
from pathlib import Path


def compiled_chunk_hlo(preset_name: str, agent: str, n: int, precision: str, program: str,
                       chunk: int) -> str:  # fmt: skip
    """The optimized HLO text of ``n`` agents' chunk as training compiles it."""
    import dataclasses

    import jax.numpy as jnp

    from advisor_jax.agent.config import preset
    from advisor_jax.training import program as programs
    from advisor_jax.training.devices import init_population, place, put
    from advisor_jax.training.population import agent_keys, build_population

    cfg, hp = preset(preset_name, agent, precision=precision)
    cfg = dataclasses.replace(cfg, chunk_steps=chunk)
    placement = place(n, 1)
    chosen = programs.resolve_program(program, placement, precision)
    _, init_fn, chunk_fn = programs.population_functions(cfg, placement, chosen)
    hp, _ = build_population(hp, {}, seeds=list(range(n)))
    state = init_population(init_fn, agent_keys(list(range(n))), placement, cfg.episodes)
    lowered = chunk_fn.lower(state, put(hp, placement), jnp.int32(0))
    return lowered.compile().as_text()


def open_text(path: Path, mode: str):
    """``path`` opened in text ``mode`` ("r" or "w"), gzip-compressed where it ends in .gz."""
    return (gzip.open if path.suffix == ".gz" else open)(path, mode + "t")


def read_hlo(path: Path) -> str:
    with open_text(path, "r") as f:
        return f.read()


def report(hlo: str, min_copy_bytes: int, listing: bool, top: int = 3) -> list[str]:
    """One line for each of the ``top`` loop bodies with the most kernels (the chunk's scans;
    the others are small inner loops) and, with ``listing``, its joining fusions."""
    from advisor_jax.bench import hlo_scopes

    comps = hlo_scopes.computations(hlo)
    bodies = sorted(hlo_scopes.loop_bodies(hlo), key=lambda b: -hlo_scopes.kernels(comps, b))
    lines = []
    for body in bodies[:top]:
        joined = hlo_scopes.joined_fusions(comps, body)
        copies = hlo_scopes.large_copies(comps, body, min_copy_bytes)
        mib = sum(b for _, b in copies) / 2**20
        lines.append(
            f"{body}: {hlo_scopes.kernels(comps, body)} kernels, "
            f"{hlo_scopes.longest_kernel_chain(comps, body)} on its longest chain of data "
            f"dependence, {len(joined)} joining the collection and the update, {len(copies)} "
            f"copies of ≥ {min_copy_bytes // 1024} KiB ({mib:.1f} MiB)"
        )
        if listing:
            lines += [f"  {j.name} {j.shape} (collect ops {j.collect_ops}, update ops "
                      f"{j.update_ops})" for j in joined]  # fmt: skip
            runs = hlo_scopes.chain_by_half(comps, body)
            lines.append("  longest chain by half: " + ", ".join(f"{h} {n}" for h, n in runs))
    return lines


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--hlo", type=Path, help="read this optimized HLO text instead")
    parser.add_argument("--preset", default="quick")
    parser.add_argument("--agent", default="ATD3+AfDP")
    parser.add_argument("--agents", type=int, default=1)
    parser.add_argument("--precision", default="fp32", choices=["fp32", "bf16"])
    parser.add_argument("--program", default="auto",
                        choices=["auto", "general", "steady", "latency-bound"])  # fmt: skip
    parser.add_argument("--chunk", type=int, default=100, help="env steps per chunk")
    parser.add_argument("--min-copy-kib", type=int, default=256)
    parser.add_argument("--top", type=int, default=3, help="loop bodies to report")
    parser.add_argument("--list", action="store_true",
                        help="list the joining fusions and the longest chain by half")  # fmt: skip
    parser.add_argument("--dump", type=Path, help="also write the HLO text here (.gz: gzip)")
    args = parser.parse_args()
    if args.hlo is not None:
        hlo = read_hlo(args.hlo)
    else:
        hlo = compiled_chunk_hlo(
            args.preset, args.agent, args.agents, args.precision, args.program, args.chunk
        )
    if args.dump is not None:
        with open_text(args.dump, "w") as f:
            f.write(hlo)
    print("\n".join(report(hlo, args.min_copy_kib * 1024, args.list, args.top)))


if __name__ == "__main__":
    main()
