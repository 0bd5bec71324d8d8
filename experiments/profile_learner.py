"""Where the learner's time goes: a device trace of ``Learner.update``, kernel by kernel.

Issue 17 asks for the breakdown before any speed work. This script runs the exact update
step that training runs (``bench_learner.make_update_loop``: replay sampling, critic step,
delayed actor step, vmapped over ``--agents``) under ``jax.profiler.trace``, reads back the
Perfetto trace that JAX writes, and sums the device time of every kernel by name and by
kind (GEMM, elementwise/fusion, reduction, copy/transpose, other). It also reports how much
of the wall-clock time of a call the device was busy (the rest is launch and host overhead)
and, in the same process, the fp32 matmul ceiling.

    python experiments/profile_learner.py --agents 128 1       # on the GPU
    python experiments/profile_learner.py --small --agents 2   # CPU smoke run

Writes ``results/profile_learner.md`` and ``.json`` (``--out``); with ``--keep-trace`` also
the gzipped trace and the compiled HLO of the first population size, and
``profile_learner_ops.md``: every kernel of that trace joined to the HLO instruction that
launched it (output shape, JAX op name), in ms per update, with each of XLA's own kernels'
bytes per launch and the GB/s they give (to hold against the device's copy rate). The join
can be redone from the kept files, without a GPU:

    python experiments/profile_learner.py --attribute TRACE.json.gz HLO.txt.gz --agents 128
"""

from __future__ import annotations

import argparse
import collections
import gzip
import json
import re
import shutil
import sys
import tempfile
import time
from pathlib import Path

import jax

from advisor_jax.agent.config import parse_agent
from advisor_jax.bench import measure, writing
from advisor_jax.bench.learner_loop import (
    SMALL,
    fill_replay,
    make_update_loop,
    require_whole_blocks,
)
from advisor_jax.bench.trace import (
    busy_us,
    device_events,
    hlo_instructions,
    hlo_name,
    instruction_bytes,
    instruction_of,
    kind_of,
    read_trace,
)
from advisor_jax.fileio import atomic_write_json
from advisor_jax.training.program import PROGRAMS

ADAM = "Adam (and the soft update) over one layer's parameters"


def role_of(shape: str, op_name: str) -> str:
    """What a memory-bound kernel does, from its output and JAX op name. Adam's passes write
    several arrays of one layer's shape (the parameter, its moments, its bf16 copy, the target
    network's) from an elementwise op; with the held critics in bf16 only
    (``Layout.bf16_critic_weights``) the last op is stochastic rounding's ``where``."""
    dims = re.findall(r"\w+\[([^\]]*)\]", shape)
    elementwise = re.search(r"/(convert_element_type|add|sub|mul|select_n)$", op_name)
    if len(dims) >= 2 and len(set(dims)) == 1 and elementwise:
        return ADAM
    for pattern, role in (
        (r"transpose\(.*_where\)+/select_n$", "ReLU's backward mask"),
        (r"relu", "ReLU"),
        (r"transpose\(.*reduce_sum", "bias gradient (reduction over the batch)"),
        (r"transpose\(.*/transpose$", "transpose of an activation (backward)"),
        (r"/add$", "bias add"),
        (r"slice", "slice"),
        (r"dot_general", "GEMM (XLA's own)"),
    ):
        if re.search(pattern, op_name):
            return role
    return ""


def attribute(events: list[dict], hlo: str, n_updates: int) -> list[dict]:
    """Kernels by name with the HLO instruction that launched them, ms per update, and for
    XLA's own kernels the bytes of the instruction's operands and output per launch
    (``trace.instruction_bytes``) and the rate that gives (GB/s, against the device's copy
    rate: which memory-bound kernels run below it)."""
    instructions = hlo_instructions(hlo)
    moved = instruction_bytes(hlo)
    rows: dict[str, dict] = {}
    for e in events:
        row = rows.setdefault(e["name"], dict(kernel=e["name"], calls=0, us=0.0))
        row["calls"] += 1
        row["us"] += e["dur"]
    for row in rows.values():
        shape, op_name = instruction_of(row["kernel"], instructions) or ("", "")
        row.update(
            kind=kind_of(row["kernel"]),
            shape=shape,
            op=op_name,
            role=role_of(shape, op_name) if shape else "",
            ms_per_update=row["us"] / n_updates / 1e3,
            calls_per_update=row["calls"] / n_updates,
        )
        launch_bytes = moved.get(hlo_name(row["kernel"], moved)) if shape else None
        if launch_bytes:
            row.update(mb_per_launch=launch_bytes / 1e6,
                       gb_per_s=launch_bytes * row["calls"] / row["us"] / 1e3)  # fmt: skip
    return sorted(rows.values(), key=lambda r: -r["us"])


def write_attribution(out: Path, rows: list[dict], title: str, command: str) -> None:
    total = sum(r["ms_per_update"] for r in rows)
    roles: dict[str, float] = collections.defaultdict(float)  # ms per update
    moved: dict[str, float] = collections.defaultdict(float)  # GB per update, XLA's kernels
    unsized: set[str] = set()  # roles with a kernel of unknown bytes (a library call)
    for r in rows:
        role = r["role"] or r["kind"]
        roles[role] += r["ms_per_update"]
        if "mb_per_launch" in r:
            moved[role] += r["mb_per_launch"] * r["calls_per_update"] / 1e3
        else:
            unsized.add(role)

    def rate(role: str) -> str:  # GB/s of a role's kernels, where all of them have bytes
        sized = role not in unsized and roles[role] > 0
        return f"{moved[role] / roles[role] * 1e3:,.0f}" if sized else ""

    atomic_write_json(out / "profile_learner_ops.json", dict(title=title, kernels=rows))
    lines = [
        "# Kernels of one update, joined to the HLO that launched them",
        "",
        f"{title}. {total:.2f} ms of kernels per vmapped update. cuBLAS GEMMs run inside",
        "CUDA graphs and carry no HLO name; XLA's own fusions do.",
        "",
        "## By role",
        "",
        *writing.markdown_table(
            ("role", "ms per update", "%", "GB per update", "GB/s"),
            [
                (k, v, 100 * v / total, f"{moved[k]:.2f}" if moved[k] else "", rate(k))
                for k, v in sorted(roles.items(), key=lambda kv: -kv[1])
            ],  # fmt: skip
            formats=("", ".3f", ".1f", "", ""),
        ),
        "",
        "## Kernels (top 40)",
        "",
        *writing.markdown_table(
            (
                "kernel",
                "calls/update",
                "ms/update",
                "MB/launch",
                "GB/s",
                "output shape",
                "role",
                "JAX op",
            ),
            [
                (
                    r["kernel"][:60],
                    r["calls_per_update"],
                    r["ms_per_update"],
                    f"{r['mb_per_launch']:,.0f}" if "mb_per_launch" in r else "",
                    f"{r['gb_per_s']:,.0f}" if "gb_per_s" in r else "",
                    r["shape"][:70],
                    r["role"],
                    r["op"][:80].replace("|", "/"),
                )
                for r in rows[:40]
            ],
            formats=("", ".1f", ".3f", "", ""),
        ),  # fmt: skip
        "",
        "MB/launch: the bytes of the HLO instruction's operands and output (each read or "
        "written once; the GEMMs in library calls have no HLO name); GB/s: those bytes at the "
        "kernel's measured time, to hold against the device's copy rate.",
        "",
        f"Command: `{command}`",
        "",
    ]
    writing.write_markdown(out / "profile_learner_ops.md", lines)


def profile(cfg, n_agents: int, n_updates: int, trace_dir: Path, program: str = "general") -> dict:
    learner, loop = make_update_loop(cfg, n_updates, program, agents_per_device=n_agents)
    keys = jax.random.split(jax.random.PRNGKey(0), n_agents)
    states = jax.jit(jax.vmap(learner.init))(keys)
    replays = jax.jit(jax.vmap(fill_replay, in_axes=(None, 0)), static_argnums=0)(
        cfg.buffer_size, keys
    )
    hlo = loop.lower(states, replays, keys).compile().as_text()
    for _ in range(2):  # compile and warm up outside the trace
        states = jax.block_until_ready(loop(states, replays, keys))
    t0 = time.perf_counter()
    states = jax.block_until_ready(loop(states, replays, keys))
    wall_untraced = time.perf_counter() - t0
    with jax.profiler.trace(str(trace_dir), create_perfetto_trace=True):
        t0 = time.perf_counter()
        states = jax.block_until_ready(loop(states, replays, keys))
        wall = time.perf_counter() - t0
    events, source, trace_file = read_trace(trace_dir)
    by_name: dict[str, list] = collections.defaultdict(lambda: [0, 0.0])
    for e in events:
        by_name[e["name"]][0] += 1
        by_name[e["name"]][1] += e["dur"]
    by_kind: dict[str, float] = collections.defaultdict(float)
    for name, (_, dur) in by_name.items():
        by_kind[kind_of(name)] += dur
    kernel_total = sum(d for _, d in by_name.values())
    top = sorted(by_name.items(), key=lambda kv: -kv[1][1])[:40]
    per_update = 1e6 / (n_agents * n_updates)  # µs of wall per agent-update, times seconds
    return dict(
        agents=n_agents,
        updates=n_updates,
        wall_s=wall,
        wall_untraced_s=wall_untraced,
        agent_updates_per_s=n_agents * n_updates / wall_untraced,
        device_busy_us=busy_us(events),
        kernel_sum_us=kernel_total,
        events=len(events),
        event_source=source,
        threads=sorted({str(e.get("tid")) for e in events})[:20],
        by_kind_us=dict(sorted(by_kind.items(), key=lambda kv: -kv[1])),
        top=[dict(name=n, kind=kind_of(n), calls=c, total_us=d) for n, (c, d) in top],
        us_per_agent_update_wall=wall * per_update,
        sample_event_args=sorted(events[0].get("args", {})) if events else [],
        _trace_file=str(trace_file),
        _hlo=hlo,
        _events=events,
    )


def main() -> None:
    parser = argparse.ArgumentParser(
        description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter
    )
    parser.add_argument("--agent", default="ATD3+AfDP")
    parser.add_argument("--agents", type=int, nargs="+", default=[128, 1])
    parser.add_argument("--updates", type=int, default=20, help="updates in the traced call")
    parser.add_argument("--small", action="store_true", help="tiny networks (CPU smoke run)")
    parser.add_argument("--precision", default="fp32", choices=["fp32", "bf16"],
                        help="the learner's precision (AgentConfig.precision)")  # fmt: skip
    parser.add_argument("--program", default="general", choices=PROGRAMS,
                        help="the training program whose update loop to trace "
                             "(learner_loop.make_update_loop)")  # fmt: skip
    parser.add_argument("--out", type=Path, default=Path("results"))
    parser.add_argument(
        "--attribute",
        nargs=2,
        type=Path,
        metavar=("TRACE", "HLO"),
        help="only join a kept trace to its HLO (first --agents, --updates)",
    )
    parser.add_argument("--keep-trace", action="store_true",
                        help="also write the first size's trace and HLO (gzipped)")  # fmt: skip
    args = parser.parse_args()
    cfg = parse_agent(args.agent, precision=args.precision, **(SMALL if args.small else {}))
    command = writing.command_line("experiments/profile_learner.py", sys.argv[1:])
    try:
        require_whole_blocks(cfg, args.updates, args.program)
    except ValueError as e:
        parser.error(f"--updates: {e}")
    if args.attribute:
        trace_file, hlo_file = args.attribute
        events, _ = device_events(json.loads(gzip.decompress(trace_file.read_bytes())))
        hlo = gzip.decompress(hlo_file.read_bytes()).decode()
        kept = trace_file.parent / "profile_learner.json"  # the run the trace was kept with
        measured = json.loads(kept.read_text()) if kept.exists() else {}
        title = (f"{cfg.name}, {args.agents[0]} agents, {args.updates} updates traced on "
                 f"{measured.get('device', '?')}, {measured.get('date', '?')}")  # fmt: skip
        args.out.mkdir(parents=True, exist_ok=True)
        write_attribution(args.out, attribute(events, hlo, args.updates), title, command)
        return
    where = measure.provenance()
    ceiling = measure.matmul_ceiling(2048 if args.small else 8192) / 1e12
    print(f"device: {where['device']} ({where['backend']}); fp32 matmul {ceiling:.1f} TFLOP/s")
    args.out.mkdir(parents=True, exist_ok=True)
    rows = []
    for i, n in enumerate(args.agents):
        with tempfile.TemporaryDirectory() as tmp:
            row = profile(cfg, n, args.updates, Path(tmp), args.program)
            if args.keep_trace and i == 0:
                shutil.copy(row["_trace_file"], args.out / "profile_learner_trace.json.gz")
                (args.out / "profile_learner_hlo.txt.gz").write_bytes(
                    gzip.compress(row["_hlo"].encode())
                )
                title = (f"{cfg.name}, {n} agents, {args.updates} updates traced on "
                         f"{where['device']}, {where['date']}")  # fmt: skip
                rows_ops = attribute(row["_events"], row["_hlo"], args.updates)
                write_attribution(args.out, rows_ops, title, command)
        for k in ("_trace_file", "_hlo", "_events"):
            row.pop(k)
        rows.append(row)
        busy = 100 * row["device_busy_us"] / (1e6 * row["wall_s"])
        print(f"agents {n}: {row['agent_updates_per_s']:,.0f} agent-updates/s, device busy "
              f"{busy:.0f} % of the traced call")  # fmt: skip
        for kind, us in row["by_kind_us"].items():
            print(f"  {kind:20s} {100 * us / row['kernel_sum_us']:5.1f} %")

    result = dict(
        **where, agent=cfg.name, matmul_ceiling_tflops=ceiling, program=args.program, rows=rows
    )
    atomic_write_json(args.out / "profile_learner.json", result)
    lines = [
        "# Where an update's time goes",
        "",
        f"{cfg.name}, batch {cfg.batch_size}, actor {cfg.actor_hidden}, critic "
        f"{cfg.critic_state_hidden}+{cfg.critic_hidden}, precision {cfg.precision}; "
        f"`Learner.update` × {args.updates} "
        f"in one jitted scan as training's {args.program} program runs it, traced with "
        "`jax.profiler`.",
        "",
        f"Device: {where['device']} ({where['backend']}), jax {where['jax']}, {where['date']}. "
        f"fp32 matmul ceiling in the same process: {ceiling:.1f} TFLOP/s.",
    ]
    for row in rows:
        total = row["kernel_sum_us"]
        lines += [
            "",
            f"## {row['agents']} agents",
            "",
            f"{row['agent_updates_per_s']:,.0f} agent-updates/s untraced; traced call "
            f"{1e3 * row['wall_s']:.1f} ms, device busy {row['device_busy_us'] / 1e3:.1f} ms "
            f"({100 * row['device_busy_us'] / (1e6 * row['wall_s']):.0f} %), kernel time summed "
            f"{total / 1e3:.1f} ms over {row['events']} kernels.",
            "",
            *writing.markdown_table(
                ("kind", "ms", "% of kernel time"),
                [(k, v / 1e3, 100 * v / total) for k, v in row["by_kind_us"].items()],
                formats=("", ".2f", ".1f"),
            ),
            "",
            *writing.markdown_table(
                ("kernel", "kind", "calls", "ms", "%"),
                [
                    (
                        t["name"][:90].replace("|", "/"),
                        t["kind"],
                        t["calls"],
                        t["total_us"] / 1e3,
                        100 * t["total_us"] / total,
                    )
                    for t in row["top"][:25]
                ],
                formats=("", "", "d", ".2f", ".1f"),
            ),  # fmt: skip
        ]
    lines += ["", f"Command: `{command}`", ""]
    writing.write_markdown(args.out / "profile_learner.md", lines)


if __name__ == "__main__":
    main()
