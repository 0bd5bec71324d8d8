"""Where a full training step's time goes: a device trace of the training chunk.

``bench_train.py`` times the chunk; ``profile_learner.py`` traces the learner alone. This
script traces the chunk itself (env, advisor, actor, Eq. 1 selector, replay insert and the
update: what training runs) for populations of ``--agents``, after a warm-up past the
learning start, and reports per environment step:

* the wall-clock time, the time the device was busy and the idle rest (launch latency,
  host synchronisation: at 1 agent a step is a chain of small kernels);
* the kernels launched, and the idle gaps between consecutive kernels by length;
* kernel time by part of the step, from the named scopes of ``training/train.py`` and
  ``Learner.update`` (collect, replay sample, critic step, actor step) that XLA keeps in
  the compiled program's op names; cuBLAS GEMMs run inside CUDA graphs without an HLO
  name and are counted as their own part;
* kernel time by kind (GEMM, elementwise, reduction, copy/transpose) and the top kernels;
* with ``--devices N`` (the population sharded as ``advisor-jax train --devices N`` shards
  it): each GPU's busy time, and the time at least one GPU was busy against their sum,
  which tells devices that run at once (the union near one device's time) from devices
  that take turns (the union near the sum). Per-step figures are then per device.

    python experiments/profile_train.py --agents 1 64 --precision bf16     # on the GPU
    python experiments/profile_train.py --agents 256 --devices 1 2 4 --precision bf16
    python experiments/profile_train.py --preset quick --agents 1 --chunk 20   # CPU smoke run

The chunk is training's program for each population (``--program auto``,
``program.choose_program``). At most ``program.latency_bound_agents`` agents per GPU that is
the latency-bound program, whose loop runs as one CUDA graph: the profiler sees the graph's
launch, not its kernels, and the report says so. ``--program steady`` traces the same
kernels without the whole-loop graph.

Writes ``results/profile_train.md`` and ``.json`` (``--out``).
"""

from __future__ import annotations

import argparse
import collections
import dataclasses
import gzip
import sys
import tempfile
import time
from pathlib import Path

import jax
import jax.numpy as jnp

from advisor_jax.agent.config import preset
from advisor_jax.bench import measure, writing
from advisor_jax.bench.trace import busy_us, hlo_instructions, instruction_of, kind_of, read_trace
from advisor_jax.fileio import atomic_write_json
from advisor_jax.training import compiler
from advisor_jax.training.devices import init_population, place, put
from advisor_jax.training.population import agent_keys, build_population
from advisor_jax.training.program import PROGRAMS, population_functions, resolve_program

# Parts of a step, tried in order on the JAX op name of the HLO that launched a kernel.
PARTS = (
    ("actor step (every d-th update)", "actor_step"),
    ("critic step", "critic_step"),
    ("replay sample", "replay_sample"),
    ("learn (rest)", "learn"),
    ("collect (env, advisor, actor, selector, noise, replay insert)", "collect"),
)
GAP_EDGES_US = (2, 5, 10, 20, 50)


def part_of(op_name: str, has_hlo_name: bool, kernel: str = "") -> str:
    if not has_hlo_name:
        if kind_of(kernel) == "collective":  # NCCL, between devices (a sharded chunk)
            return "collective between devices (NCCL, no HLO name)"
        return "library call (cuBLAS in a CUDA graph, no HLO name)"
    for part, scope in PARTS:
        if f"/{scope}/" in f"/{op_name}/":
            return part
    return "chunk (bookkeeping outside the scopes)"


def gaps_us(events: list[dict]) -> list[float]:
    """Idle time between each kernel's end and the next kernel's start (µs, ≥ 0)."""
    spans = sorted((e["ts"], e["ts"] + e["dur"]) for e in events)
    out, end = [], None
    for start, stop in spans:
        if end is not None:
            out.append(max(0.0, start - end))
        end = stop if end is None else max(end, stop)
    return out


def largest_first(totals: dict[str, float]) -> list[tuple[str, float]]:
    return sorted(totals.items(), key=lambda kv: -kv[1])


def by_device(events: list[dict]) -> dict[int, list[dict]]:
    """The kernel events of each device (a trace process per GPU), in trace order."""
    out: dict[int, list[dict]] = collections.defaultdict(list)
    for e in events:
        out[e["pid"]].append(e)
    return dict(sorted(out.items()))


def device_rows(groups: dict[int, list[dict]], steps: int) -> tuple[list[dict], float]:
    """Per device of ``groups`` (``by_device``): busy µs and kernels per step; and the µs
    per step at least one device was busy (the union of every device's kernels)."""
    rows = [
        dict(device=pid, busy_us_per_step=busy_us(evs) / steps, kernels_per_step=len(evs) / steps)
        for pid, evs in groups.items()
    ]
    return rows, busy_us([e for evs in groups.values() for e in evs]) / steps


def profile(cfg, hp, n_agents: int, trace_dir: Path, devices: int = 1, program="auto") -> dict:
    """One traced chunk of ``n_agents`` on ``devices``, warm (compiled, past the learning
    start), placed as training places it (padded and sharded on the agent axis); ``program``:
    the chunk's (``program.PROGRAMS``; "auto": training's choice for the placement)."""
    placement = place(n_agents, devices)
    program = resolve_program(program, placement, cfg.agent.precision)
    _, init_fn, chunk_fn = population_functions(cfg, placement, program)
    hp, _ = build_population(hp, {}, seeds=list(range(n_agents)))
    hp = put(hp, placement)
    keys = agent_keys(list(range(n_agents)))
    state, step = init_population(init_fn, keys, placement, cfg.episodes), 0
    compiled = chunk_fn.lower(state, hp, jnp.int32(step)).compile()  # runs, and has the HLO

    def chunk():
        nonlocal state, step
        state, _ = compiled(state, hp, jnp.int32(step))
        step += cfg.chunk_steps
        return state

    while step * cfg.envs_per_agent < cfg.agent.warmup + cfg.chunk_steps:
        jax.block_until_ready(chunk())
    _, untraced = measure.run_timed(chunk)
    hlo = compiled.as_text()
    with jax.profiler.trace(str(trace_dir), create_perfetto_trace=True):
        _, wall = measure.run_timed(chunk)
    events, source, _ = read_trace(trace_dir)
    instructions = hlo_instructions(hlo)
    steps = cfg.chunk_steps
    groups = by_device(events) if source.startswith("device") else {0: events}  # a CPU: one
    per_device, any_busy = device_rows(groups, steps)
    n_dev = len(per_device) or 1  # per-step figures below: per device
    by_part: dict[str, float] = collections.defaultdict(float)
    by_kind: dict[str, float] = collections.defaultdict(float)
    by_name: dict[str, list] = collections.defaultdict(lambda: [0, 0.0, "", ("", "")])
    for e in events:
        name = e["name"]
        shape_op = instruction_of(name, instructions)
        part = part_of(shape_op[1] if shape_op else "", shape_op is not None, name)
        by_part[part] += e["dur"]
        by_kind[kind_of(name)] += e["dur"]
        row = by_name[name]
        row[:] = row[0] + 1, row[1] + e["dur"], part, shape_op or ("", "")
    gaps = [g for evs in groups.values() for g in gaps_us(evs)]
    edges = (0, *GAP_EDGES_US, float("inf"))
    gap_bins = {
        f"{lo:g}-{hi:g} µs": (sum(lo <= g < hi for g in gaps) / steps / n_dev,
                              sum(g for g in gaps if lo <= g < hi) / steps / n_dev)
        for lo, hi in zip(edges[:-1], edges[1:], strict=True)
    }  # fmt: skip
    per_step = lambda us: us / steps / n_dev  # noqa: E731
    # WHOLE_LOOPS as the compile read it (a profile may replace it to see the loop's kernels)
    whole_loops = "WHILE" in compiler.WHOLE_LOOPS["xla_gpu_enable_command_buffer"].split(",")
    return dict(
        _hlo=hlo,
        agents=n_agents,
        devices=devices,
        program=program,
        whole_loop_graph=whole_loops,
        steps=steps,
        agent_steps_per_s=n_agents * steps * cfg.envs_per_agent / untraced,
        wall_us_per_step=1e6 * wall / steps,
        wall_untraced_us_per_step=1e6 * untraced / steps,
        busy_us_per_step=sum(d["busy_us_per_step"] for d in per_device) / n_dev,
        kernels_per_step=len(events) / steps / n_dev,
        per_device=per_device,
        any_device_busy_us_per_step=any_busy,
        event_source=source,
        gaps_per_step={k: dict(count=c, us=us) for k, (c, us) in gap_bins.items()},
        part_us_per_step={k: per_step(v) for k, v in largest_first(by_part)},
        kind_us_per_step={k: per_step(v) for k, v in largest_first(by_kind)},
        top=[dict(name=n, calls_per_step=per_step(c), us_per_step=per_step(d), part=p,
                  shape=shape, op=op)
             for n, (c, d, p, (shape, op)) in sorted(by_name.items(),
                                                     key=lambda kv: -kv[1][1])[:40]],
    )  # fmt: skip


def _device_lines(r: dict) -> list[str]:
    """Each device's busy time, and whether they ran at once (several devices only)."""
    devices = r.get("per_device", [])
    if len(devices) < 2:
        return []
    total = sum(d["busy_us_per_step"] for d in devices)
    union, wall = r["any_device_busy_us_per_step"], r["wall_us_per_step"]
    return [
        *writing.markdown_table(
            ("device (trace process)", "busy µs per step", "busy %", "kernels per step"),
            [(d["device"], d["busy_us_per_step"], 100 * d["busy_us_per_step"] / wall,
              d["kernels_per_step"]) for d in devices],
            formats=("", ".0f", ".0f", ".1f"),
        ),
        "",
        f"At least one device busy {union:.0f} µs per step, against {total:.0f} µs summed "
        f"over the devices and {max(d['busy_us_per_step'] for d in devices):.0f} µs on the "
        "busiest: near the busiest, the devices run at once; near the sum, they take turns. "
        "The figures below are per device.",
        "",
    ]  # fmt: skip


def _program_lines(r: dict) -> list[str]:
    """The chunk's program; under the latency-bound one on a GPU, that its kernels are hidden."""
    program = r.get("program", "auto")
    line = f"The chunk's program: {program}."
    whole_loops = r.get("whole_loop_graph", True)  # rows written before the field: it held
    if program == "latency-bound" and whole_loops and r["event_source"].startswith("device"):
        line += (
            " Its loop runs as one CUDA graph: the trace holds the graph's launches, not the"
            " kernels inside, so the tables below miss most of the step. `--program steady`"
            " traces the same kernels without the whole-loop graph."
        )
    return [line, ""]


def report(rows: list[dict], title: str, command: str) -> list[str]:
    lines = ["# Where a training step's time goes", "", title]
    if any(not r["event_source"].startswith("device") for r in rows):
        lines += ["", "No GPU in the trace: the events below are the host's (a smoke run)."]
    for r in rows:
        idle = r["wall_us_per_step"] - r["busy_us_per_step"]
        on = f" on {r['devices']} devices" if r.get("devices", 1) > 1 else ""
        lines += [
            "",
            f"## {r['agents']} agent{'s' if r['agents'] > 1 else ''}{on}",
            "",
            *_program_lines(r),
            *_device_lines(r),
            f"{r['agent_steps_per_s']:,.0f} agent env-steps/s untraced "
            f"({r['wall_untraced_us_per_step']:.0f} µs per population step). Traced: "
            f"{r['wall_us_per_step']:.0f} µs per step, the device busy "
            f"{r['busy_us_per_step']:.0f} µs ({100 * r['busy_us_per_step'] / r['wall_us_per_step']:.0f} %),"  # noqa: E501
            f" idle {idle:.0f} µs; {r['kernels_per_step']:.1f} kernels per step.",
            "",
            *writing.markdown_table(
                ("part of the step", "kernel µs per step", "%"),
                [
                    (k, v, 100 * v / sum(r["part_us_per_step"].values()))
                    for k, v in r["part_us_per_step"].items()
                ],
                formats=("", ".1f", ".1f"),
            ),  # fmt: skip
            "",
            *writing.markdown_table(
                ("kind", "kernel µs per step"),
                list(r["kind_us_per_step"].items()),
                formats=("", ".1f"),
            ),
            "",
            "Idle gaps between consecutive kernels, per step:",
            "",
            *writing.markdown_table(
                ("gap", "count", "µs"),
                [(k, v["count"], v["us"]) for k, v in r["gaps_per_step"].items()],
                formats=("", ".1f", ".1f"),
            ),
            "",
            *writing.markdown_table(
                ("kernel", "calls per step", "µs per step", "part", "output shape", "JAX op"),
                [
                    (
                        t["name"][:70].replace("|", "/"),
                        t["calls_per_step"],
                        t["us_per_step"],
                        t["part"],
                        t["shape"][:60],
                        t["op"][-90:].replace("|", "/"),
                    )
                    for t in r["top"][:25]
                ],
                formats=("", ".2f", ".1f", "", "", ""),
            ),  # fmt: skip
        ]
    return [*lines, "", f"Command: `{command}`", ""]


def main() -> None:
    parser = argparse.ArgumentParser(
        description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter
    )
    parser.add_argument("--preset", default="paper")
    parser.add_argument("--agent", default="ATD3+AfDP")
    parser.add_argument("--agents", type=int, nargs="+", default=[1, 64])
    parser.add_argument("--chunk", type=int, default=100, help="env steps in the traced chunk")
    parser.add_argument("--devices", type=int, nargs="+", default=[1],
                        help="shard each population over this many devices (each count "
                             "in turn), as advisor-jax train --devices does")  # fmt: skip
    parser.add_argument("--precision", default="fp32", choices=["fp32", "bf16"],
                        help="the learner's precision (AgentConfig.precision)")  # fmt: skip
    parser.add_argument("--program", default="auto", choices=["auto", *PROGRAMS],
                        help="the chunk's program (program.PROGRAMS); auto: training's choice, "
                             "the latency-bound one for small populations, whose whole-loop "
                             "CUDA graph hides its kernels from the trace")  # fmt: skip
    parser.add_argument("--out", type=Path, default=Path("results"))
    parser.add_argument("--keep-hlo", action="store_true",
                        help="also write each size's compiled HLO (gzipped text)")  # fmt: skip
    args = parser.parse_args()
    if min(args.agents) < 1 or args.chunk < 1:
        parser.error(f"--agents and --chunk must be ≥ 1, got {args.agents} and {args.chunk}")
    if min(args.devices) < 1 or max(args.devices) > jax.device_count():
        parser.error(f"--devices {args.devices}: this machine has {jax.device_count()}")
    cfg, hp = preset(args.preset, args.agent, precision=args.precision)
    cfg = dataclasses.replace(cfg, chunk_steps=args.chunk, episodes=100_000)
    where = measure.provenance()
    rows = []
    for n, devices in [(n, d) for d in args.devices for n in args.agents]:
        t0 = time.perf_counter()
        with tempfile.TemporaryDirectory() as tmp:
            rows.append(profile(cfg, hp, n, Path(tmp), devices, args.program))
        r = rows[-1]
        hlo = r.pop("_hlo")
        if args.keep_hlo:
            args.out.mkdir(parents=True, exist_ok=True)
            name = f"profile_train_hlo_{n}" + (f"_{devices}dev" if devices > 1 else "")
            (args.out / f"{name}.txt.gz").write_bytes(gzip.compress(hlo.encode()))
        print(f"agents {n}, devices {devices}: {r['agent_steps_per_s']:,.0f} agent env-steps/s, "
              f"{r['wall_us_per_step']:.0f} µs per step traced, busy "
              f"{r['busy_us_per_step']:.0f} µs, {r['kernels_per_step']:.1f} kernels "
              f"({time.perf_counter() - t0:.0f} s)")  # fmt: skip
    atomic_write_json(
        args.out / "profile_train.json",
        dict(**where, preset=args.preset, agent=args.agent, precision=args.precision,
             chunk=args.chunk, rows=rows),
    )  # fmt: skip
    title = (f"{args.agent}, preset `{args.preset}`, learner {args.precision}, one traced "
             f"chunk of {args.chunk} env steps after a warm-up past the learning start; "
             f"{where['device']} ({where['backend']}), jax {where['jax']}, "
             f"{where['date']}.")  # fmt: skip
    command = writing.command_line("experiments/profile_train.py", sys.argv[1:])
    writing.write_markdown(args.out / "profile_train.md", report(rows, title, command))


if __name__ == "__main__":
    main()
