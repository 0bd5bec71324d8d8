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

from advisor_jax.bench.trace import HLO_LINE, shape_bytes
from advisor_jax.training.collectives import hlo_computations

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
        if m and m.group(3) == "copy" and shape_bytes(m.group(2)) >= min_bytes:
            out.append((m.group(2), shape_bytes(m.group(2))))
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


def longest_kernel_chain(comps: dict[str, list[str]], body: str) -> int:
    """Kernels (fusions, library calls, copies) on the longest path of data dependence
    through loop ``body``: a lower bound on how many of them must run one after another.
    A GPU's graph of the body may add dependencies through buffers XLA reuses."""
    depth: dict[str, int] = {}
    for line in comps[body]:
        m = HLO_LINE.match(line)
        if not m:
            continue
        before = max((depth.get(o, 0) for o in operands(line, m.group(3))), default=0)
        depth[m.group(1)] = before + (m.group(3) in KERNEL_OPS)
    return max(depth.values(), default=0)
