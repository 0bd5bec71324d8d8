"""Trains a small population's learner with the first-layer kernel, sharded over 2 forced CPU
devices, and prints what tests/agent/test_masked_wgrad.py checks of it.

    python tests/agent/masked_wgrad_worker.py STATES.npz [fp32|bf16]

(bf16: the kernel that takes its mask from the layer's input, ``weight_gradient_from_input``.)

Prints one JSON object: ``collectives`` (those of the sharded update's optimized HLO,
``collectives.find_collectives``), ``plain_collectives`` (the same with the kernel batched
by ``jax.vmap`` of the bare Pallas call, what the partitioner cannot split: the check must
catch it); it saves the start, the one-device and the sharded learner states to STATES.npz.
XLA's CPU device count is fixed when JAX starts, hence a process of its own.
"""

from __future__ import annotations

import functools
import json
import os
import sys

DEVICES = 2
os.environ["JAX_PLATFORMS"] = "cpu"
# The suite's compile flags (tests/conftest.py), which the test passes on, and the devices.
os.environ["XLA_FLAGS"] = (
    os.environ.get("XLA_FLAGS", "--xla_backend_optimization_level=0")
    + f" --xla_force_host_platform_device_count={DEVICES}"
)
sys.path.insert(0, os.path.join(os.path.dirname(__file__), "..", ".."))

import jax  # noqa: E402
import numpy as np  # noqa: E402

from advisor_jax.agent import masked_wgrad, networks  # noqa: E402
from advisor_jax.agent.config import HParams, parse_agent  # noqa: E402
from advisor_jax.agent.learner import make_learner  # noqa: E402
from advisor_jax.bench.learner_loop import SMALL, fill_replay  # noqa: E402
from advisor_jax.training.collectives import find_collectives  # noqa: E402
from advisor_jax.training.devices import place  # noqa: E402

AGENTS = 4
SIZES = dict(actor_hidden=(16, 16), critic_state_hidden=24, critic_hidden=(16, 16))
PRECISION = sys.argv[2] if len(sys.argv) > 2 else "fp32"
CFG = parse_agent("ATD3+AfDP", **{**SMALL, **SIZES, "batch_size": 40, "buffer_size": 256,
                                  "precision": PRECISION})  # fmt: skip
KERNEL = "weight_gradient_from_input" if PRECISION == "bf16" else "weight_gradient"
"""The batched kernel the learner's first layer calls (``gemm_layers``)."""


def population_update():
    """(init, update) of ``AGENTS`` learners with the kernel: a critic step and, at index 0,
    the delayed actor step (both steps' backward passes through the first layer)."""
    learner = make_learner(CFG, layout=networks.Layout(True, True, True))
    replay = fill_replay(CFG.buffer_size, jax.random.key(1))

    def update(state, keys):
        state, _, _ = learner.update(state, learner.sample(replay, keys[0]), keys[1], HParams(), 0)
        return state

    return jax.vmap(learner.init), jax.vmap(update)


def main() -> None:
    assert len(jax.devices()) == DEVICES, jax.devices()
    init, update = population_update()
    keys = jax.random.split(jax.random.key(0), AGENTS)
    step_keys = jax.random.split(jax.random.key(7), (AGENTS, 2))
    start = init(keys)
    one = jax.jit(update)(start, step_keys)
    agents = place(AGENTS, DEVICES).agents()
    sharded = jax.jit(update, in_shardings=agents, out_shardings=agents)
    two = sharded(jax.device_put(start, agents), jax.device_put(step_keys, agents))
    hlo = sharded.lower(start, step_keys).compile().as_text()
    real = getattr(masked_wgrad, KERNEL)
    bare = functools.partial(masked_wgrad.kernel, from_input=PRECISION == "bf16")
    setattr(masked_wgrad, KERNEL, bare)  # the bare call, batched by jax.vmap
    try:
        _, plain = population_update()
        plain_hlo = jax.jit(plain, in_shardings=agents, out_shardings=agents).lower(
            start, step_keys).compile().as_text()  # fmt: skip
    finally:
        setattr(masked_wgrad, KERNEL, real)
    leaves = {"start": start, "one": one, "two": two}
    np.savez(sys.argv[1], **{f"{name}/{i}": np.asarray(leaf) for name, tree in leaves.items()
                      for i, leaf in enumerate(jax.tree.leaves(tree))})  # fmt: skip
    print(json.dumps({
        "collectives": [c._asdict() for c in find_collectives(hlo)],
        "plain_collectives": [c._asdict() for c in find_collectives(plain_hlo)],
    }))  # fmt: skip


if __name__ == "__main__":
    main()
