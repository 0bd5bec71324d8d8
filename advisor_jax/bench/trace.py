"""Reading a ``jax.profiler`` trace: the device's kernel events, how long the device was busy,
what kind each kernel is and which HLO instruction launched it (``profile_learner.py``,
``profile_train.py``)."""

from __future__ import annotations

import gzip
import json
import re
from pathlib import Path

from advisor_jax.agent import masked_wgrad
from advisor_jax.training.collectives import type_bytes

KINDS = (
    ("our Pallas kernel", re.compile(masked_wgrad.KERNEL_NAME)),
    ("collective", re.compile(r"^nccl")),
    ("gemm", re.compile(r"gemm|xmma|cutlass|wgmma|cublas|sm90_|sm80_|matmul|dot|triton_gemm")),
    ("copy/transpose", re.compile(r"transpose|copy|memcpy|memset|concatenate|slice|pad")),
    ("reduction", re.compile(r"reduce|reduction|row_reduction|column_reduction|scatter|sort")),
    ("elementwise fusion", re.compile(r"fusion|loop_|input_|broadcast|select|add|multiply")),
)


def kind_of(name: str) -> str:
    low = name.lower()
    for kind, pattern in KINDS:
        if pattern.search(low):
            return kind
    return "other"


def device_events(trace: dict) -> tuple[list[dict], str]:
    """Kernel events of the trace and where they came from.

    On a GPU, JAX's trace has a process per device with a thread per CUDA stream (one event
    per kernel) beside "XLA Ops" and "XLA Modules" threads that repeat the same time at op
    and module level: only the stream threads are kept. Elsewhere (a CPU) all events are.
    """
    events = [e for e in trace.get("traceEvents", []) if e.get("ph") == "X" and "dur" in e]
    meta = [e for e in trace.get("traceEvents", []) if e.get("ph") == "M"]
    process = {e["pid"]: e.get("args", {}).get("name", "") for e in meta
               if e.get("name") == "process_name"}  # fmt: skip
    thread = {(e["pid"], e["tid"]): e.get("args", {}).get("name", "") for e in meta
              if e.get("name") == "thread_name"}  # fmt: skip
    devices = {pid for pid, name in process.items() if re.search(r"/device:gpu", name, re.I)}
    for pattern in (r"^stream", r"xla ops"):
        chosen = [
            e
            for e in events
            if e["pid"] in devices
            and re.search(pattern, thread.get((e["pid"], e["tid"]), ""), re.I)
        ]
        if chosen:
            return chosen, f"device threads matching {pattern!r}"
    return events, "all events (no GPU process in the trace)"


def busy_us(events: list[dict]) -> float:
    """Union of the events' intervals (µs): time the device had at least one kernel running."""
    spans = sorted((e["ts"], e["ts"] + e["dur"]) for e in events)
    total, end = 0.0, -float("inf")
    for start, stop in spans:
        if stop <= end:
            continue
        total += stop - max(start, end)
        end = stop
    return total


HLO_LINE = re.compile(r"\s*(?:ROOT )?%([\w.\-]+) = (\(.*?\)|\S+) ([\w-]+)\(")
JAX_PREFIX = re.compile(r"^jit\([^)]*\)/(vmap\(\)/)?(while/body/)?(eval_jaxpr/)?")


def hlo_instructions(hlo: str) -> dict[str, tuple[str, str]]:
    """HLO instruction name → (output shape, JAX op name of its metadata)."""
    out = {}
    for line in hlo.splitlines():
        m = HLO_LINE.match(line)
        if m:
            op_name = re.search(r'op_name="([^"]*)"', line)
            out[m.group(1)] = (m.group(2), JAX_PREFIX.sub("", op_name.group(1) if op_name else ""))
    return out


def instruction_bytes(hlo: str) -> dict[str, int]:
    """HLO instruction name → the bytes of its operands and its output: what one launch of its
    kernel reads and writes if it touches each operand once (an upper bound where a kernel
    reads a slice of an operand, a lower one where it reads an operand more than once)."""
    shapes, operands = {}, {}
    for line in hlo.splitlines():
        m = HLO_LINE.match(line)
        if m:
            shapes[m.group(1)] = m.group(2)
            args = line[m.end() : line.find(")", m.end())]
            operands[m.group(1)] = re.findall(r"%([\w.\-]+)", args)
    return {
        name: type_bytes(shapes[name]) + sum(type_bytes(shapes.get(o, "")) for o in args)
        for name, args in operands.items()
    }


def instruction_of(kernel: str, instructions: dict[str, tuple[str, str]]) -> tuple[str, str] | None:
    """(output shape, JAX op name) of the HLO instruction that launched ``kernel`` (XLA names
    the kernel of ``fusion.3`` ``fusion_3``); None for kernels without one (library calls)."""
    return instructions.get(hlo_name(kernel, instructions))


def hlo_name(kernel: str, instructions: dict) -> str:
    """The HLO instruction name of ``kernel`` (XLA names the kernel of ``fusion.3``
    ``fusion_3``) where ``instructions`` has it, else the kernel's own name."""
    dotted = re.sub(r"_(\d+)$", r".\1", kernel)
    return dotted if dotted in instructions else kernel


def read_trace(trace_dir: Path) -> tuple[list[dict], str, Path]:
    """``device_events`` of the Perfetto trace ``jax.profiler.trace`` wrote under
    ``trace_dir``, and the trace file."""
    files = sorted(trace_dir.rglob("perfetto_trace.json.gz"))
    if not files:
        raise RuntimeError(f"jax.profiler wrote no perfetto_trace.json.gz under {trace_dir}")
    events, source = device_events(json.loads(gzip.decompress(files[-1].read_bytes())))
    return events, source, files[-1]
