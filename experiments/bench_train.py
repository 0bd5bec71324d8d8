"""Training throughput: agent environment steps per second of the full jitted chunk.

One environment step of an agent = advisor + actor + Eq. 1 selector (2 critic calls) + OU
noise + MJX env step + replay insert + `updates_per_step` updates (critic every step, actor
every d-th). ``bench_learner.py`` times the updates alone; the gap between the two is the
cost of data collection and bookkeeping.

    python experiments/bench_train.py --preset paper --agents 8 32 64
    python experiments/bench_train.py --preset quick --agents 1 4 --chunk 100   # CPU
    # the cost of the simulated P3DX (envs/motion.py) against the kinematic robot
    python experiments/bench_train.py --agents 16 64 --motion mjx --name bench_train_mjx
    # several GPUs: the same populations on 1 and 2 devices, in one process
    python experiments/bench_train.py --agents 64 128 --devices 1 2 --name bench_multigpu

``--reference TREE`` also runs the benchmark of another checkout (the commit before a speed
change) in a subprocess of the same command, with the same options, and the table gives
both side by side (``measure.run_reference``).

Writes ``results/<name>.md`` / ``.json`` (``--name``, default bench_train). With several
``--devices`` counts each population is timed on each, sharded as ``advisor-jax train
--devices`` shards it (``advisor_jax.training.devices``), and the table gives the speed-up
over the first count. A warm-up chunk (compile + the first steps, before the buffer holds a
batch) is excluded from the timing.
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

from advisor_jax.bench import measure, writing
from advisor_jax.bench.full_step import PROGRAMS, full_step
from advisor_jax.fileio import atomic_write_json


def reference_lines(rows: list[dict], reference: dict | None, tree: Path | None) -> list[str]:
    """The table of this tree's rows against the same rows of ``--reference``'s run."""
    if reference is None:
        return []
    before = {(r["agents"], r["devices"], r["precision"]): r for r in reference["rows"]}
    pairs = [(r, before.get((r["agents"], r["devices"], r["precision"]))) for r in rows]
    return [
        "",
        f"Against `{tree}` (run in the same command, same options):",
        "",
        *writing.markdown_table(
            (
                "precision",
                "agents",
                "devices",
                "reference agent env-steps/s",
                "this tree",
                "speed-up",
            ),
            [
                (
                    r["precision"],
                    r["agents"],
                    r["devices"],
                    b["agent_steps_per_s"],
                    r["agent_steps_per_s"],
                    r["agent_steps_per_s"] / b["agent_steps_per_s"],
                )
                for r, b in pairs
                if b is not None
            ],
            formats=("", "", "", ",.0f", ",.0f", ".2f"),
            align="r",
        ),  # fmt: skip
    ]


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--preset", default="paper")
    parser.add_argument("--agent", default="ATD3+AfDP")
    parser.add_argument("--agents", type=int, nargs="+", default=[8, 32, 64])
    parser.add_argument("--chunk", type=int, default=500, help="env steps per jitted call")
    parser.add_argument("--repeats", type=int, default=3)
    parser.add_argument(
        "--devices",
        type=int,
        nargs="+",
        default=[1],
        help="device counts to time each population on (default 1)",
    )
    parser.add_argument(
        "--precision",
        nargs="+",
        default=["fp32"],
        choices=["fp32", "bf16"],
        help="learner precisions to time (AgentConfig.precision; default fp32)",
    )
    parser.add_argument(
        "--program",
        default="auto",
        choices=PROGRAMS,
        help="the chunk's program: auto (as training picks it, program.choose_program), "
        "general (a lax.cond per step for warm-up and the TD3 delay), steady (past warm-up "
        "no conditional in the loop) or latency-bound (the steady program with overlapping "
        "kernels and whole-loop graphs: more memory; before 2026-11-27 named 'steady')",
    )
    parser.add_argument(
        "--motion",
        default="kinematic",
        help="motion model of the arena: kinematic, mjx or mjx:KEY=VALUE,...",
    )
    parser.add_argument("--name", default="bench_train", help="report file name")
    parser.add_argument("--out", type=Path, default=Path("results"))
    parser.add_argument("--reference", type=Path, metavar="TREE",
                        help="also run this checkout's benchmark and compare")  # fmt: skip
    args = parser.parse_args()
    reference = None
    if args.reference:
        argv = ["--preset", args.preset, "--agent", args.agent, "--agents", *map(str, args.agents),
                "--chunk", str(args.chunk), "--repeats", str(args.repeats),
                "--devices", *map(str, args.devices), "--precision", *args.precision,
                "--name", args.name]  # fmt: skip
        if args.motion != "kinematic":  # older trees have no --motion (and are kinematic)
            argv += ["--motion", args.motion]
        print(f"reference: {args.reference}")
        reference = measure.run_reference(
            args.reference, "bench_train.py", argv, f"{args.name}.json"
        )

    where = measure.provenance()
    device = f"{where['device']} ({where['backend']}), jax {where['jax']}"
    print(f"device: {device}")
    rows = []
    for precision in args.precision:
        for n in args.agents:
            for d in args.devices:
                rows.append(
                    full_step(
                        args.preset,
                        args.agent,
                        n,
                        d,
                        precision,
                        args.chunk,
                        args.repeats,
                        args.motion,
                        args.program,
                    )  # fmt: skip
                )
                base = next(  # the first device count, same population and precision
                    r for r in rows if r["agents"] == n and r["precision"] == precision
                )
                rows[-1]["speedup"] = rows[-1]["agent_steps_per_s"] / base["agent_steps_per_s"]
                print(
                    f"{precision} agents {n:4d} on {d} device(s): "
                    f"{rows[-1]['agent_steps_per_s']:10.0f} agent env-steps/s "
                    f"(x{rows[-1]['speedup']:.2f}), warm-up {rows[-1]['warmup_s']:.1f} s"
                )

    if reference is not None:  # the other tree's rows, and which tree
        reference = dict(tree=str(args.reference), rows=reference["rows"])
    result = dict(
        **where,
        preset=args.preset,
        agent=args.agent,
        motion=args.motion,
        program=args.program,
        chunk=args.chunk,
        rows=rows,
        reference=reference,
        command=writing.command_line("experiments/bench_train.py", sys.argv[1:]),
    )
    atomic_write_json(args.out / f"{args.name}.json", result)
    lines = [
        "# Training throughput (full step: env + advisor + selector + update)",
        "",
        f"{args.agent}, preset `{args.preset}`, motion `{args.motion}`, {args.chunk} env steps "
        "per jitted chunk; "
        f"{device}, {result['date']}.",
        "",
        *writing.markdown_table(
            (
                "precision",
                "agents",
                "devices",
                "program",
                "agent env-steps/s",
                "speed-up",
                "s per chunk",
            ),
            [
                (
                    r["precision"],
                    r["agents"],
                    r["devices"],
                    r["program"],
                    r["agent_steps_per_s"],
                    r["speedup"],
                    r["seconds_per_chunk"],
                )
                for r in rows
            ],
            formats=("", "", "", "", ",.0f", ".2f", ".3f"),
            align="r",
        ),
        "",
        "Speed-up: over the first device count, same population and precision.",
        *reference_lines(rows, reference, args.reference),
        "",
        f"Command: `{result['command']}`",
    ]
    writing.write_markdown(args.out / f"{args.name}.md", lines)


if __name__ == "__main__":
    main()
