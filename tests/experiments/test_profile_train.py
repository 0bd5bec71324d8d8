"""experiments/profile_train.py: kernels are attributed to the parts of a training step by
the named scopes of the training chunk, which must therefore reach the program; idle gaps
are measured between consecutive kernels."""

from __future__ import annotations

import re

import jax.numpy as jnp
import pytest

from advisor_jax.agent.config import HParams
from advisor_jax.training.population import agent_keys, build_population
from advisor_jax.training.program import population_functions
from tests.experiments.scripts import load_script
from tests.training.conftest import TINY

profile_train = load_script("profile_train")

PREFIX = "jit(chunk)/vmap()/while/body/closed_call/learn/cond/branch_1_fun/while/body/"


@pytest.mark.parametrize(
    ("op_name", "part"),
    [
        (PREFIX + "closed_call/actor_step/cond/branch_1_fun/jvp(Actor)/hidden_0/dot_general",
         "actor step (every d-th update)"),
        (PREFIX + "closed_call/critic_step/transpose(jvp(Critic))/state/add", "critic step"),
        (PREFIX + "replay_sample/gather", "replay sample"),
        ("jit(chunk)/vmap()/while/body/learn/add", "learn (rest)"),
        ("jit(chunk)/vmap()/while/body/collect/Actor/hidden_0/dot_general",
         "collect (env, advisor, actor, selector, noise, replay insert)"),
        ("jit(chunk)/vmap()/while/body/add", "chunk (bookkeeping outside the scopes)"),
        ("jit(chunk)/vmap()/while/body/collector/add", "chunk (bookkeeping outside the scopes)"),
    ],
)  # fmt: skip
def test_parts_from_op_names(op_name, part):
    assert profile_train.part_of(op_name, has_hlo_name=True) == part


def test_kernels_without_an_hlo_name_are_library_calls():
    assert profile_train.part_of("", has_hlo_name=False).startswith("library call")


def test_nccl_kernels_are_collectives_not_cublas():
    """The sharded chunk's all-gathers (results/profile_train_multigpu/) were first counted
    as cuBLAS calls."""
    from advisor_jax.bench.trace import kind_of

    kernel = "ncclDevKernel_AllGather_RING_LL(ncclDevKernelArgsStorage<4096ul>)"
    assert profile_train.part_of("", False, kernel).startswith("collective between devices")
    assert kind_of(kernel) == "collective"
    assert kind_of("nvjet_sm90_tst_128x256_64x4_2x1_v_badd_coopA_NNN") == "gemm"
    assert kind_of("masked_weight_gradient") == "our Pallas kernel"


def test_gaps_between_kernels_overlaps_count_as_none():
    events = [dict(ts=0, dur=5), dict(ts=3, dur=4), dict(ts=10, dur=1), dict(ts=30, dur=2)]
    assert profile_train.gaps_us(events) == [0.0, 3.0, 19.0]


def test_the_training_chunk_carries_the_named_scopes():
    _, init_fn, chunk_fn = population_functions(TINY)
    hp, _ = build_population(HParams(), {}, seeds=[0])
    text = chunk_fn.lower(init_fn(agent_keys([0])), hp, jnp.int32(0)).as_text(debug_info=True)
    for scope in ("collect", "learn", "replay_sample", "critic_step", "actor_step"):
        assert re.search(rf'["/]{scope}/', text), scope


def test_devices_that_run_at_once_are_told_from_devices_that_take_turns():
    at_once = [dict(pid=1, ts=0, dur=10), dict(pid=2, ts=0, dur=10),
               dict(pid=1, ts=20, dur=10), dict(pid=2, ts=21, dur=10)]  # fmt: skip
    turns = [dict(pid=1, ts=0, dur=10), dict(pid=2, ts=10, dur=10),
             dict(pid=1, ts=20, dur=10), dict(pid=2, ts=30, dur=10)]  # fmt: skip
    for events, union in ((at_once, 21.0), (turns, 40.0)):
        groups = profile_train.by_device(events)
        rows, any_busy = profile_train.device_rows(groups, steps=2)
        assert [(r["device"], r["busy_us_per_step"], r["kernels_per_step"]) for r in rows] == [
            (1, 10.0, 1.0), (2, 10.0, 1.0)
        ]  # fmt: skip
        assert any_busy == union / 2
    row = dict(per_device=rows, any_device_busy_us_per_step=any_busy, wall_us_per_step=25.0)
    text = "\n".join(profile_train._device_lines(row))
    assert "20 µs per step, against 20 µs summed" in text  # the turns: union = sum
    assert profile_train._device_lines(dict(per_device=rows[:1])) == []


def test_the_report_says_when_a_whole_loop_graph_hides_the_kernels():
    def lines(program, source, whole_loop_graph=True):
        row = dict(program=program, event_source=source, whole_loop_graph=whole_loop_graph)
        return " ".join(profile_train._program_lines(row))

    assert "The chunk's program: general." == lines("general", "device").strip()
    assert "not the kernels inside" in lines("latency-bound", "device")
    assert "not the kernels inside" not in lines("latency-bound", "host")  # no GPU: nothing hidden
    # a profile that took WHILE out of compiler.WHOLE_LOOPS traced the loop's kernels
    assert "not the kernels inside" not in lines("latency-bound", "device", False)
