"""Compiles sharded population chunks on N forced CPU devices and prints their collectives.

    python tests/training/collectives_worker.py DEVICES CASE [CASE ...]

CASE is ``tiny`` (the TINY population of conftest.py, 5 agents: one padding agent on 2
devices), ``lfd`` (test_lfd.py's TINY_LFD: a gated baseline, whose chunk gate is a min over
all agents), ``injected`` (TINY with one cross-agent reduction injected into the step:
Eq. 1's ε from the population's least-trained agent, ``lax.pmin`` over the agent axis) or
``held`` (TINY's general program with the layout a GPU's fp32 learners get there: the GEMM
layers and the critics held through the chunk, ``agent/held_critics.py``; the first-layer
kernel left out, whose partitioning has a test of its own).
Prints one JSON object, case -> the chunk's collectives (``collectives.find_collectives``,
as dicts). XLA's CPU device count is fixed when JAX starts, hence a process of its own;
tests/training/test_collectives.py runs it.
"""

from __future__ import annotations

import contextlib
import json
import os
import sys

DEVICES = int(sys.argv[1])
CASES = sys.argv[2:]
os.environ["JAX_PLATFORMS"] = "cpu"
# The suite's compile flags (tests/conftest.py), which the test passes on, and the devices.
os.environ["XLA_FLAGS"] = (
    os.environ.get("XLA_FLAGS", "--xla_backend_optimization_level=0")
    + f" --xla_force_host_platform_device_count={DEVICES}"
)
sys.path.insert(0, os.path.join(os.path.dirname(__file__), "..", ".."))

import jax  # noqa: E402

from advisor_jax.training import train  # noqa: E402
from advisor_jax.training.collectives import find_collectives, sharded_chunk_hlo  # noqa: E402
from advisor_jax.training.devices import AXIS  # noqa: E402
from tests.training.conftest import RUN_SEEDS, TINY  # noqa: E402


@contextlib.contextmanager
def held_critics_layout():
    """Every program gets the GEMM layers with the critics held, as a GPU's fp32 general
    program does (``program.program_layout``), while this is active."""
    from advisor_jax.agent.networks import Layout
    from advisor_jax.training import program

    real = program.program_layout
    program.program_layout = lambda *_, **__: Layout(layers_in_gemm=True, held_critics=True)
    try:
        yield
    finally:
        program.program_layout = real


@contextlib.contextmanager
def least_trained_epsilon():
    """Every agent's Eq. 1 selector sees the smallest episode count of the population: a
    per-step reduction over the agents (a plausible bug), traced while this is active."""
    real = train.select_action

    def select_action(key, actor_action, advisor_action, q_actor, q_advisor, episodes, hp):
        episodes = jax.lax.pmin(episodes, AXIS)
        return real(key, actor_action, advisor_action, q_actor, q_advisor, episodes, hp)

    train.select_action = select_action
    try:
        yield
    finally:
        train.select_action = real


def main() -> None:
    assert len(jax.devices()) == DEVICES, jax.devices()
    out = {}
    for case in CASES:
        if case == "lfd":
            from tests.training.test_lfd import TINY_LFD

            hlo = sharded_chunk_hlo(TINY_LFD, len(RUN_SEEDS), DEVICES)
        elif case == "held":
            with held_critics_layout():
                hlo = sharded_chunk_hlo(TINY, len(RUN_SEEDS), DEVICES, "general")
        elif case == "injected":
            with least_trained_epsilon():
                hlo = sharded_chunk_hlo(TINY, len(RUN_SEEDS), DEVICES)
        else:
            assert case == "tiny", case
            hlo = sharded_chunk_hlo(TINY, len(RUN_SEEDS), DEVICES)
        out[case] = [c._asdict() for c in find_collectives(hlo)]
    print(json.dumps(out))


if __name__ == "__main__":
    main()
