"""A step draws its update's minibatch before it stores its transition (training/train.py).

Both halves of a step read the state it starts from: the update is the learner's update on
the batch drawn from the buffer as the step found it, the step's transition is stored after
the update, and the first update comes once the buffer held ``warmup`` transitions before the
step. These tests compute one step's update by hand from the pieces and compare.
"""

from __future__ import annotations

import dataclasses

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from advisor_jax.agent.config import HParams
from advisor_jax.training.train import make_core, make_train
from tests.compare import assert_same_training
from tests.training.conftest import TINY

HP = HParams(lr_actor=1e-3)


@pytest.fixture(scope="module")
def after_warmup_chunk():
    """One agent's state after TINY's first 40-step chunk (its buffer holds 40 of its
    transitions, past the warm-up of one batch, 32) and that chunk's metrics."""
    trainer = make_train(TINY)
    state = jax.jit(trainer.init)(jax.random.key(3))  # as training: jitted (eager: ~10 s)
    state, metrics = jax.jit(trainer.chunk)(state, HP, jnp.int32(0))
    return jax.device_get(state), jax.device_get(metrics)


def test_the_first_update_comes_once_the_buffer_held_warmup_transitions_before_the_step(
    after_warmup_chunk,
):
    _, metrics = after_warmup_chunk
    warmup = TINY.agent.warmup  # 32: steps 0..31 find fewer than 32 transitions stored
    loss = np.asarray(metrics["loss/critic"])
    assert np.all(np.isnan(loss[:warmup]))
    assert np.all(np.isfinite(loss[warmup:]))


def test_a_steps_update_is_the_update_on_the_buffer_before_its_transition(after_warmup_chunk):
    state, _ = after_warmup_chunk
    one_step = dataclasses.replace(TINY, chunk_steps=1)
    first_step = TINY.chunk_steps  # 40, a block head for d = 2: the actor step too
    after, _ = jax.jit(make_train(one_step).chunk)(state, HP, jnp.int32(first_step))

    # By hand: the step's keys (collect splits the state's key in three and keeps the
    # first; the draw splits that), then the learner's update on a batch drawn from the
    # buffer the step started from.
    learner = make_core(one_step).learner
    collect_key = jax.random.split(state.key, 3)[0]
    _, k_updates = jax.random.split(collect_key)
    _, k_sample, k_critic = jax.random.split(k_updates, 3)
    batch = learner.sample(state.replay, k_sample)
    by_hand, _, _ = jax.jit(learner.update)(
        state.learner, batch, k_critic, HP, jnp.int32(first_step), state.episodes
    )

    assert_same_training(after.learner, by_hand, state.learner, "one step against by hand")
    # ... and the transition stored after the update, in the next free slot.
    slot = int(state.replay.position)
    assert int(after.replay.size) == int(state.replay.size) + 1
    np.testing.assert_array_equal(after.replay.data.obs[slot], state.env.obs[0])
    np.testing.assert_array_equal(after.replay.data.obs[:slot], state.replay.data.obs[:slot])


def test_a_chunks_last_transition_is_stored_as_one_within_a_chunk(after_warmup_chunk):
    """Steps 40..79 as one chunk and as two: step 59's transition ends a chunk in one run
    and not in the other; the runs must not tell them apart."""
    state, _ = after_warmup_chunk
    whole = jax.jit(make_train(TINY).chunk)(state, HP, jnp.int32(40))[0]
    half = jax.jit(make_train(dataclasses.replace(TINY, chunk_steps=20)).chunk)
    halves = half(half(state, HP, jnp.int32(40))[0], HP, jnp.int32(60))[0]
    for a, b in zip(jax.tree.leaves(whole.replay), jax.tree.leaves(halves.replay), strict=True):
        np.testing.assert_array_equal(a, b)
    assert_same_training(halves.learner, whole.learner, state.learner, "two chunks against one")


def test_the_single_step_loop_copies_no_field_of_the_buffer():
    """The general program (every CPU's) stores the pending transition before the step's
    draw, so its compile writes the buffer in place. A store after the draw in the same step
    had a CPU copy buffer fields every step, with an optimization barrier too (0.82×,
    ``results/bench_draw_first/``)."""
    trainer = make_train(TINY)
    state = jax.eval_shape(trainer.init, jax.random.key(0))  # shapes are all a compile needs
    chunk = jax.jit(trainer.chunk, donate_argnums=0)  # as the host loop: in place
    hlo = chunk.lower(state, HP, jnp.int32(0)).compile().as_text()
    fields = [leaf.shape for leaf in jax.tree.leaves(state.replay.data) if leaf.ndim == 2]
    assert fields  # obs, action, advisor_action, next_obs: [buffer_size, ...]
    shapes = {f"= f32[{','.join(map(str, shape))}]" for shape in fields}
    copies = [
        line for line in hlo.splitlines() if " copy(" in line and any(s in line for s in shapes)
    ]
    assert not copies, copies[:3]


def _raw(leaf):
    """A leaf as numpy can compare it: a PRNG key as its data."""
    is_key = jnp.issubdtype(leaf.dtype, jax.dtypes.prng_key)
    return jax.random.key_data(leaf) if is_key else leaf


def test_a_free_store_trains_as_the_store_after_the_update(after_warmup_chunk):
    """The steady blocks' two stores (``draws.store_after``, ``draws.store_free``) put the
    same transition in the same slot before the same draw: the same chunk. Everything but the
    learner bit for bit; the learner to rounding, as the CPU compiles the two programs'
    updates apart and may round them apart (``tests/compare.py``)."""
    state, _ = after_warmup_chunk  # 40 steps: past warm-up, a block head for d = 2
    ends = []
    for free in (False, True):
        trainer = make_train(TINY, steady=True, free_store=free)
        assert trainer.steady
        ends.append(jax.jit(trainer.chunk)(state, HP, jnp.int32(TINY.chunk_steps))[0])
    rest = [jax.tree.map(_raw, end.replace(learner=None)) for end in ends]
    for a, b in zip(jax.tree.leaves(rest[0]), jax.tree.leaves(rest[1]), strict=True):
        np.testing.assert_array_equal(a, b)
    assert_same_training(ends[1].learner, ends[0].learner, state.learner, "free store")
