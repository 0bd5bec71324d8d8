"""Cross-device collectives of a compiled program, and where they sit.

A population sharded along its agent axis (``devices``) should compile to a program whose
chunk scan exchanges nothing between devices: every agent is independent. This module reads
the optimized HLO text of a compiled program (``jitted.lower(...).compile().as_text()``) and
lists its collectives (all-reduce, all-gather, reduce-scatter, collective-permute,
all-to-all, collective-broadcast, and their async ``-start`` halves), each with its result
shape, its size in bytes on one device, whether it runs inside a ``while`` loop (the chunk
scan, or any loop nested in it: paid every step) or outside every loop (once per call), and
the JAX op and source line XLA recorded for it.

    python experiments/hlo_collectives.py --preset quick --agents 4 --devices 2

``sharded_chunk_hlo`` compiles the population's sharded chunk (``program.
population_functions``) from abstract shapes, without running it. Call it in a process
that sees at least ``devices`` devices (on CPU: ``XLA_FLAGS=--xla_force_host_platform_
device_count=N`` set before JAX starts).
"""

from __future__ import annotations

import dataclasses
import math
import os
import re
from pathlib import Path
from typing import NamedTuple

COLLECTIVE_OPS = (
    "all-reduce",
    "all-gather",
    "reduce-scatter",
    "collective-permute",
    "all-to-all",
    "ragged-all-to-all",
    "collective-broadcast",
)
_DTYPE_BYTES = {
    "pred": 1, "s8": 1, "u8": 1, "s16": 2, "u16": 2, "f16": 2, "bf16": 2, "s32": 4, "u32": 4,
    "f32": 4, "s64": 8, "u64": 8, "f64": 8, "c64": 8, "c128": 16, "f8e4m3fn": 1, "f8e5m2": 1,
}  # fmt: skip
# "  %name = TYPE opcode(" or "  ROOT %name = TYPE opcode(" (TYPE may be a tuple "(...)")
_INSTRUCTION = re.compile(r"^\s*(?:ROOT\s+)?%?([\w.\-]+)\s*=\s*(.*?)\s+([a-z][\w\-]*)\(")
_HEADER = re.compile(r"^(ENTRY\s+)?%?([\w.\-]+)\s.*\{\s*$")
_CALLED = re.compile(
    r"(?:condition|body|to_apply|calls|true_computation|false_computation)=%?([\w.\-]+)"
)
_BRANCHES = re.compile(r"branch_computations=\{([^}]*)\}")
_ARRAY = re.compile(r"\b([a-z]+\d*(?:e\d+m\d+\w*)?)\[([\d,]*)\]")


class Collective(NamedTuple):
    op: str  # e.g. "all-reduce" (an async pair counts once, as its "-start")
    shape: str  # result type as XLA prints it, layouts dropped
    bytes: int  # size of the result on one device
    computation: str  # the HLO computation that holds it
    in_loop: bool  # inside some while loop's body or condition (nested calls included)
    source: str  # the JAX op_name and source_file:line of its metadata ("" if none)


@dataclasses.dataclass
class _Computation:
    name: str
    entry: bool
    lines: list[str]


def hlo_computations(hlo: str) -> list[_Computation]:
    """The module's computations (name, whether ENTRY, instruction lines), in text order."""
    out, current = [], None
    for line in hlo.splitlines():
        if current is None:
            m = _HEADER.match(line)
            if m and "=" not in line.split("(", 1)[0]:
                current = _Computation(m.group(2), bool(m.group(1)), [])
        elif line.strip() == "}":
            out.append(current)
            current = None
        else:
            current.lines.append(line)
    return out


def _called(line: str) -> list[str]:
    names = _CALLED.findall(line)
    for group in _BRANCHES.findall(line):
        names += [n.strip().lstrip("%") for n in group.split(",") if n.strip()]
    return names


def type_bytes(hlo_type: str) -> int:
    """Bytes of an HLO type such as ``f32[2,64]{1,0}`` or a tuple of them."""
    total = 0
    for dtype, dims in _ARRAY.findall(hlo_type):
        if dtype in _DTYPE_BYTES:
            total += _DTYPE_BYTES[dtype] * math.prod(int(d) for d in dims.split(",") if d)
    return total


def _tables(hlo: str) -> dict[str, dict[int, str]]:
    """The module's FileNames, FunctionNames, FileLocations and StackFrames tables."""
    tables: dict[str, dict[int, str]] = {}
    current = None
    for line in hlo.splitlines():
        if line in ("FileNames", "FunctionNames", "FileLocations", "StackFrames"):
            current = tables.setdefault(line, {})
            continue
        m = re.match(r"^(\d+) (.*)$", line) if current is not None else None
        if m:
            current[int(m.group(1))] = m.group(2)
        else:
            current = None
    return tables


def _field(text: str, name: str) -> int:
    return int(re.search(rf"\b{name}=(\d+)", text).group(1))


def _frames(tables: dict[str, dict[int, str]], frame: int, depth: int = 3) -> list[str]:
    """``file:line function`` of a stack frame and its callers, innermost first, at most
    ``depth`` distinct ones, paths relative to the repository. (A traced function's frames
    can recur in the chain, once for the trace of a scan body and once for the op in it:
    each is listed once.)"""
    files, funcs = tables.get("FileNames", {}), tables.get("FunctionNames", {})
    locations, frames = tables.get("FileLocations", {}), tables.get("StackFrames", {})
    out: list[str] = []
    seen = set()
    while frame in frames and frame not in seen and len(out) < depth:
        seen.add(frame)
        location = locations[_field(frames[frame], "file_location_id")]
        file = files[_field(location, "file_name_id")].strip('"')
        function = funcs[_field(location, "function_name_id")].strip('"')
        where = f"{_relative(file)}:{_field(location, 'line')} {function}"
        if where not in out:
            out.append(where)
        frame = _field(frames[frame], "parent_frame_id") - 1  # printed 1-based, 0: none
    return out


def _relative(file: str) -> str:
    root = str(Path(__file__).resolve().parents[2]) + os.sep
    return os.path.normpath(file).removeprefix(root)


def _source(line: str, tables: dict[str, dict[int, str]]) -> str:
    name = re.search(r'op_name="([^"]*)"', line)
    parts = [name.group(1)] if name else []
    frame = re.search(r"stack_frame_id=(\d+)", line)
    file = re.search(r'source_file="([^"]*)"', line)
    if frame:
        parts.append(" < ".join(_frames(tables, int(frame.group(1)))))
    elif file:
        where = re.search(r"source_line=(\d+)", line)
        parts.append(f"{_relative(file.group(1))}:{where.group(1) if where else '?'}")
    return " @ ".join(parts)


def find_collectives(hlo: str) -> list[Collective]:
    """Every collective of an optimized HLO module's text, in the order of the text."""
    comps, tables = hlo_computations(hlo), _tables(hlo)
    calls = {c.name: [n for line in c.lines for n in _called(line)] for c in comps}
    looped: set[str] = set()  # computations reachable from a while's body or condition
    stack = []
    for c in comps:
        for line in c.lines:
            if re.search(r"\swhile\(", line):
                stack += re.findall(r"(?:condition|body)=%?([\w.\-]+)", line)
    while stack:
        name = stack.pop()
        if name not in looped:
            looped.add(name)
            stack += calls.get(name, [])
    found = []
    for c in comps:
        for line in c.lines:
            m = _INSTRUCTION.match(line)
            if not m:
                continue
            result, opcode = m.group(2), m.group(3)
            base = opcode.removesuffix("-start")
            if base not in COLLECTIVE_OPS or opcode.endswith("-done"):
                continue
            shape = re.sub(r"\{[\d,]*\}", "", result)
            found.append(
                Collective(
                    opcode,
                    shape,
                    type_bytes(result),
                    c.name,
                    c.name in looped,
                    _source(line, tables),
                )
            )
    return found


def sharded_chunk_hlo(cfg, n_agents: int, devices: int, program: str | None = None) -> str:
    """Optimized HLO text of ``cfg``'s population chunk, ``n_agents`` agents sharded over
    the first ``devices`` devices as ``run_training`` shards them (compiled, not run);
    ``program``: the chunk's program (``program.PROGRAMS``; None or "auto": as training
    picks it)."""
    import jax
    import jax.numpy as jnp

    from advisor_jax.agent.config import default_hparams
    from advisor_jax.training.devices import pad, place
    from advisor_jax.training.population import agent_keys, build_population
    from advisor_jax.training.program import population_functions

    placement = place(n_agents, devices)
    _, init_fn, chunk_fn = population_functions(cfg, placement, program)
    hp, _ = build_population(default_hparams(cfg.agent), {}, seeds=list(range(n_agents)))

    def abstract(tree):
        sharding = placement.agents()
        return jax.tree.map(
            lambda a: jax.ShapeDtypeStruct(a.shape, a.dtype, sharding=sharding), tree
        )

    keys = abstract(jax.eval_shape(lambda k: pad(k, placement), agent_keys(list(range(n_agents)))))
    state = abstract(jax.eval_shape(init_fn, keys))
    hp = abstract(jax.eval_shape(lambda h: pad(h, placement), hp))
    step = jax.ShapeDtypeStruct((), jnp.int32, sharding=placement.replicated())
    return chunk_fn.lower(state, hp, step).compile().as_text()
