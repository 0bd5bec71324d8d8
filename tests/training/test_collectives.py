"""The sharded chunk exchanges nothing between devices inside its scan.

The agents of a population are independent, so a population sharded along its agent axis
must compile to a program with no collective inside the chunk's while loop (one would be
paid at every environment step). tests/training/collectives_worker.py compiles the chunk on 2
forced CPU devices and lists the optimized HLO's collectives
(``advisor_jax.training.collectives``). That is the CPU compile: XLA's GPU compile of the
same sharded program (jax 0.11.2) all-gathers inside TD3's delayed actor step, which no
CPU test can see (results/multigpu_hlo.md, "On GPUs").

Two workers run at once (XLA's compiles are mostly single-threaded): the TINY population
and the same with a cross-agent reduction injected into its step (the check must catch
it); LfD, a gated baseline whose chunk gate (a min over every agent) is the one
collective the program may hold, once per chunk, outside the loop, and TINY with the critics
held as a GPU's fp32 general program holds them (``agent/held_critics.py``).
"""

from __future__ import annotations

import json
import os
import subprocess
import sys
from pathlib import Path

import pytest

from advisor_jax.training.collectives import find_collectives, type_bytes

WORKER = Path(__file__).with_name("collectives_worker.py")


@pytest.fixture(scope="module")
def compiled(tmp_path_factory):
    """case -> the collectives of its compiled 2-device chunk (dicts)."""
    root = tmp_path_factory.mktemp("collectives")
    env = dict(os.environ)  # with the suite's XLA_FLAGS: the worker adds its devices
    procs = []
    for cases in (["tiny", "injected"], ["lfd", "held"]):
        out = root / f"{cases[0]}.json"
        with out.open("w") as sink:  # a file, not a pipe: a full pipe would block
            procs.append((subprocess.Popen([sys.executable, str(WORKER), "2", *cases],
                                           env=env, stdout=sink, stderr=subprocess.PIPE,
                                           text=True), out))  # fmt: skip
    found = {}
    for proc, out in procs:
        _, err = proc.communicate(timeout=600)
        assert proc.returncode == 0, err[-3000:]
        found.update(json.loads(out.read_text()))
    return found


def _in_loop(collectives):
    return [c for c in collectives if c["in_loop"]]


def _listed(collectives) -> str:
    return "\n".join(
        f"{c['op']} {c['shape']} ({c['bytes']} B) {'in the loop' if c['in_loop'] else 'outside'}"
        f": {c['source']}"
        for c in collectives
    )


def test_sharded_chunk_has_no_collective(compiled):
    """ATD3+AfDP, 5 agents on 2 devices (one padding agent): nothing inside the scan, and
    nothing outside it either (a once-per-chunk collective would cost little, but none is
    needed: update this test if one is added on purpose)."""
    inside = _in_loop(compiled["tiny"])
    assert not inside, "collectives paid at every step:\n" + _listed(inside)
    assert not compiled["tiny"], "collectives once per chunk:\n" + _listed(compiled["tiny"])


def test_held_critics_exchange_nothing(compiled):
    """Holding and releasing the critics at the chunk's ends, and Adam on the held matrices
    inside it, are each agent's own: no collective anywhere."""
    assert not compiled["held"], _listed(compiled["held"])


def test_gated_baseline_reduces_once_per_chunk(compiled):
    """LfD: the chunk gate's min over the agents, 4 bytes, outside the loop; nothing inside."""
    assert _in_loop(compiled["lfd"]) == []
    (gate,) = compiled["lfd"]
    assert gate["op"] == "all-reduce" and gate["bytes"] == 4
    assert "phases.py" in gate["source"] and "chunk_gate" in gate["source"]


def test_check_catches_a_per_step_cross_agent_reduction(compiled):
    """The injected pmin over the agents in Eq. 1's selector: an all-reduce inside the loop,
    traced to its line."""
    (reduce,) = _in_loop(compiled["injected"])
    assert reduce["op"] == "all-reduce"
    assert "select_action" in reduce["source"] and "train.py" in reduce["source"]


HLO = """HloModule m

%sum (a: f32[], b: f32[]) -> f32[] {
  %a = f32[] parameter(0)
  %b = f32[] parameter(1)
  ROOT %add = f32[] add(%a, %b)
}

%fused (p: f32[2,8]) -> f32[2,8] {
  %p = f32[2,8]{1,0} parameter(0)
  ROOT %ar = f32[2,8]{1,0} all-reduce(%p), replica_groups={}, to_apply=%sum
}

%body (t: (s32[], f32[2,8])) -> (s32[], f32[2,8]) {
  %t = (s32[], f32[2,8]{1,0}) parameter(0)
  %x = f32[2,8]{1,0} get-tuple-element(%t), index=1
  %c = f32[2,8]{1,0} call(%x), to_apply=%fused
  %s = (f32[2,8]{1,0}, u32[]) collective-permute-start(%x), source_target_pairs={{0,1}}
  %d = f32[2,8]{1,0} collective-permute-done(%s)
  %i = s32[] get-tuple-element(%t), index=0
  ROOT %r = (s32[], f32[2,8]{1,0}) tuple(%i, %c)
}

%cond (t: (s32[], f32[2,8])) -> pred[] {
  %t = (s32[], f32[2,8]{1,0}) parameter(0)
  ROOT %p = pred[] constant(true)
}

ENTRY %main (x: f32[2,8]) -> f32[4,8] {
  %x = f32[2,8]{1,0} parameter(0)
  %g = f32[4,8]{1,0} all-gather(%x), dimensions={0}, metadata={op_name="jit(f)/gather"}
  %z = s32[] constant(0)
  %t = (s32[], f32[2,8]{1,0}) tuple(%z, %x)
  %w = (s32[], f32[2,8]{1,0}) while(%t), condition=%cond, body=%body
  ROOT %o = f32[4,8]{1,0} copy(%g)
}
"""


def test_find_collectives_places_each_one():
    """A hand-written module: a collective in a computation the loop body calls counts as
    inside, an async pair once (its start), one in the entry as outside."""
    got = {(c.op, c.in_loop, c.bytes) for c in find_collectives(HLO)}
    assert got == {
        ("all-reduce", True, 64),
        ("collective-permute-start", True, 68),
        ("all-gather", False, 128),
    }
    assert [c.source for c in find_collectives(HLO) if c.op == "all-gather"] == ["jit(f)/gather"]
    assert type_bytes("(bf16[3,2]{1,0}, pred[])") == 13
    assert type_bytes("(bf16[2,3]{1,0}, f32[4]{0}, pred[])") == 12 + 16 + 1
    assert type_bytes("s32[5]") == 20
