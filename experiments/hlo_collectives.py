"""Collectives of the sharded training chunk: which, how large, inside the scan or not.

Compiles (does not run) the population chunk of each ``--agent`` with ``--agents`` agents
sharded over ``--devices`` devices, exactly as ``advisor-jax train --devices`` shards it,
and lists every cross-device collective of the optimized HLO with its size on one device,
whether it sits inside a while loop (the chunk scan: paid every step) or outside (once per
chunk), and the JAX op and source line it came from (``advisor_jax.training.collectives``).

    python experiments/hlo_collectives.py --preset quick --agents 4 --devices 2
    python experiments/hlo_collectives.py --agent ATD3+AfDP LfD MCP+MF --dump /tmp/hlo

On a CPU-only machine the devices are forced host devices (XLA_FLAGS
``--xla_force_host_platform_device_count``, set here before JAX starts); on a GPU host
``--platform gpu`` compiles for the real devices instead. **The two differ**: the CPU
compile of a 256-agent ATD3+AfDP chunk on two devices has no collective, the GPU compile
(jax 0.11.2, H200) has 20 all-gathers inside the scan (results/multigpu_hlo.md), so a GPU
answer needs a GPU:

    python experiments/hlo_collectives.py --platform gpu --preset paper --agents 256 \
        --chunk 100 --precision bf16 [--program general|steady|latency-bound]
"""

from __future__ import annotations

import argparse
import os
import sys
from pathlib import Path


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--preset", default="quick")
    parser.add_argument("--agent", nargs="+", default=["ATD3+AfDP"])
    parser.add_argument("--agents", type=int, default=4, help="population size")
    parser.add_argument("--devices", type=int, default=2)
    parser.add_argument("--chunk", type=int, default=20, help="env steps per chunk")
    parser.add_argument("--platform", default="cpu", choices=["cpu", "gpu"])
    parser.add_argument("--precision", default="fp32", choices=["fp32", "bf16"],
                        help="the learner's precision (AgentConfig.precision)")  # fmt: skip
    parser.add_argument("--program", default="auto",
                        choices=["auto", "general", "steady", "latency-bound"],
                        help="the chunk's program (program.PROGRAMS; auto: as training "
                        "picks it)")  # fmt: skip
    parser.add_argument("--dump", type=Path, help="folder for the optimized HLO texts")
    args = parser.parse_args()
    if args.platform == "cpu":
        os.environ["JAX_PLATFORMS"] = "cpu"
        flag = f"--xla_force_host_platform_device_count={args.devices}"
        os.environ["XLA_FLAGS"] = f"{os.environ.get('XLA_FLAGS', '')} {flag}".strip()

    import dataclasses

    import jax

    from advisor_jax.agent.config import preset
    from advisor_jax.training.collectives import find_collectives, sharded_chunk_hlo

    print(f"jax {jax.__version__}, {len(jax.devices())} {jax.devices()[0].platform} devices")
    total_in_loop = 0
    for name in args.agent:
        cfg, _ = preset(args.preset, name, precision=args.precision)
        cfg = dataclasses.replace(cfg, chunk_steps=args.chunk)
        hlo = sharded_chunk_hlo(cfg, args.agents, args.devices, args.program)
        if args.dump:
            args.dump.mkdir(parents=True, exist_ok=True)
            (args.dump / f"{name.replace('+', '_')}.hlo.txt").write_text(hlo)
        found = find_collectives(hlo)
        print(f"\n{name}: {len(found)} collective(s), {args.agents} agents on {args.devices}")
        for c in found:
            where = "IN LOOP" if c.in_loop else "outside"
            print(f"  {c.op:20s} {c.shape:28s} {c.bytes:8d} B  {where:8s} {c.source}")
        total_in_loop += sum(c.in_loop for c in found)
    sys.exit(1 if total_in_loop else 0)


if __name__ == "__main__":
    main()
