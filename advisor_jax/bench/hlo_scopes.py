"""Which kernels of a compiled training chunk join its collection and its update, read from
the optimized HLO text (``experiments/hlo_fusion_scopes.py``).

A step's collection and update read the state the step starts from and nothing of each other
(``training/draws.py``), so a GPU could run their kernels side by side. XLA's fusion can
still put ops of both into one kernel: sibling fusion merges consumers of one operand, and
the collection and the update read the same parameters. Such a kernel waits for the inputs
of both halves (whether that sets a step's pace is for a timing to say:
``results/bench_collect_learn_overlap/``). The named scopes of
``train.make_train`` ("collect", "learn") and of the learner ("critic_step", "actor_step")
label every op's metadata, so a fusion's ops say which halves it holds.

Also listed: the copies of large arrays (the replay buffer) inside a loop body, which XLA
inserts where an in-place store would overwrite what a read still needs.
"""

from __future__ import annotations

import re
from typing import NamedTuple

from advisor_jax.bench.trace import HLO_LINE
from advisor_jax.training.collectives import hlo_computations, type_bytes

NAME = re.compile(r"%([\w.\-]+)")
KERNEL_OPS = ("fusion", "custom-call", "copy")
WHILE_BODY = re.compile(r"\bwhile\(.*?body=%?([\w.\-]+)")
CALLS = re.compile(r"calls=%?([\w.\-]+)")
OP_NAME = re.compile(r'op_name="([^"]*)"')

COLLECT_FORWARD = re.compile(r"/collect/(?:.*/)?(?:dot_general|Actor/)")
"""A collection op of a forward pass: the actor's layers or the selector's critic products
(Eq. 1), not its key splits or counters."""

UPDATE_STEP = re.compile(r"/(?:critic_step|actor_step)/")
"""An op of a learner update step (its losses, gradients, Adam), not its draw."""


def computations(hlo: str) -> dict[str, list[str]]:
    """HLO computation name → its instruction lines (``collectives.hlo_computations``)."""
    return {c.name: c.lines for c in hlo_computations(hlo)}


def loop_bodies(hlo: str) -> list[str]:
    """Names of the computations that are while-loop bodies (a chunk's scans)."""
    return list(dict.fromkeys(WHILE_BODY.findall(hlo)))


def op_names(lines: list[str]) -> list[str]:
    return [m.group(1) for line in lines if (m := OP_NAME.search(line))]


class Joined(NamedTuple):
    name: str  # the fusion instruction
    shape: str  # its output shape
    collect_ops: int  # its collection forward ops
    update_ops: int  # its update-step ops


def joined_fusions(comps: dict[str, list[str]], body: str) -> list[Joined]:
    """The fusions of loop ``body`` holding both an op of the collection's forward passes
    (``COLLECT_FORWARD``) and an op of an update step (``UPDATE_STEP``)."""
    out = []
    for line in comps[body]:
        m, calls = HLO_LINE.match(line), CALLS.search(line)
        if not m or m.group(3) != "fusion" or not calls:
            continue
        names = op_names(comps.get(calls.group(1), []))
        collect = sum(bool(COLLECT_FORWARD.search(n)) for n in names)
        update = sum(bool(UPDATE_STEP.search(n)) for n in names)
        if collect and update:
            out.append(Joined(m.group(1), m.group(2), collect, update))
    return out


def large_copies(comps: dict[str, list[str]], body: str, min_bytes: int) -> list[tuple[str, int]]:
    """(shape, bytes) of every ``copy`` in loop ``body`` of at least ``min_bytes``."""
    out = []
    for line in comps[body]:
        m = HLO_LINE.match(line)
        if m and m.group(3) == "copy" and type_bytes(m.group(2)) >= min_bytes:
            out.append((m.group(2), type_bytes(m.group(2))))
    return out


def kernels(comps: dict[str, list[str]], body: str) -> int:
    """Fusions, library calls and copies of loop ``body``: its kernels, about."""
    return sum(
        1 for line in comps[body] if (m := HLO_LINE.match(line)) and m.group(3) in KERNEL_OPS
    )


def operands(line: str, op: str) -> list[str]:
    """Names of the instructions ``line``'s ``op`` reads (its parenthesised operand list)."""
    rest, depth = line[line.index(op + "(") + len(op) + 1 :], 0
    for i, ch in enumerate(rest):
        depth += {"(": 1, ")": -1}.get(ch, 0)
        if depth < 0:
            return NAME.findall(rest[:i])
    return NAME.findall(rest)


def kernel_chain(comps: dict[str, list[str]], body: str) -> list[str]:
    """The kernels (fusions, library calls, copies) on the longest path of data dependence
    through loop ``body``, in order: a lower bound on how many of them must run one after
    another. A GPU's graph of the body may add dependencies through buffers XLA reuses (the
    1-agent chunk's did not lengthen it: ``results/bench_separate_outputs/``)."""
    depth: dict[str, int] = {}
    before: dict[str, tuple[str | None, bool]] = {}
    for line in comps[body]:
        m = HLO_LINE.match(line)
        if not m:
            continue
        reads = [o for o in operands(line, m.group(3)) if o in depth]
        last = max(reads, key=depth.__getitem__, default=None)
        is_kernel = m.group(3) in KERNEL_OPS
        depth[m.group(1)] = (depth[last] if last else 0) + is_kernel
        before[m.group(1)] = (last, is_kernel)
    chain, name = [], max(depth, key=depth.__getitem__, default=None)
    while name is not None:
        last, is_kernel = before[name]
        if is_kernel:
            chain.append(name)
        name = last
    return chain[::-1]


def longest_kernel_chain(comps: dict[str, list[str]], body: str) -> int:
    """How many kernels ``kernel_chain`` holds."""
    return len(kernel_chain(comps, body))


def half(op_name: str) -> str:
    """Which part of a step an op's named scope puts it in: "update" (a learner update step),
    "draw" (the minibatch's sampling), "collect" or "other"."""
    if UPDATE_STEP.search(op_name):
        return "update"
    if "/replay_sample/" in op_name:
        return "draw"
    return "collect" if "/collect/" in op_name else "other"


def kernel_op_name(comps: dict[str, list[str]], line: str) -> str:
    """A kernel's op name: its own metadata's, else (a fusion without) its fused root's."""
    own = op_names([line])
    if not own and (calls := CALLS.search(line)):
        own = op_names(comps.get(calls.group(1), []))[-1:]
    return own[0] if own else ""


def chain_by_half(comps: dict[str, list[str]], body: str) -> list[tuple[str, int]]:
    """``kernel_chain`` as runs of consecutive kernels of one ``half``. Where a step's update
    waits for its collection, a collection run comes right before a draw or an update run."""
    lines = {m.group(1): line for line in comps[body] if (m := HLO_LINE.match(line))}
    runs: list[tuple[str, int]] = []
    for name in kernel_chain(comps, body):
        part = half(kernel_op_name(comps, lines[name]))
        if runs and runs[-1][0] == part:
            runs[-1] = (part, runs[-1][1] + 1)
        else:
            runs.append((part, 1))
    return runs
