"""Replay ring buffer: wrap-around, size saturation, valid-slot sampling, shapes, errors."""

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from advisor_jax.agent.replay_buffer import Transition, replay_add, replay_init, replay_sample


def _numbered(start: int, n: int) -> Transition:
    """n transitions whose every field encodes its serial number start..start+n-1."""
    ids = np.arange(start, start + n, dtype=np.float32)
    return Transition(
        obs=np.repeat(ids[:, None], 20, axis=1),
        action=np.stack([ids, -ids], axis=1),
        advisor_action=np.stack([ids + 0.5, ids], axis=1),
        reward=ids,
        next_obs=np.repeat(ids[:, None] + 1, 20, axis=1),
        terminal=ids % 2,
    )


def test_init_shapes():
    state = replay_init(7)
    assert state.data.obs.shape == (7, 20) and state.data.next_obs.shape == (7, 20)
    assert state.data.action.shape == (7, 2) and state.data.advisor_action.shape == (7, 2)
    assert state.data.reward.shape == (7,) and state.data.terminal.shape == (7,)
    assert int(state.size) == 0 and int(state.position) == 0
    assert state.size.dtype == jnp.int32 and state.position.dtype == jnp.int32


def test_wraparound_and_saturation():
    add = jax.jit(replay_add)
    state = replay_init(5)
    state = add(state, _numbered(0, 3))  # slots 0,1,2
    assert (int(state.position), int(state.size)) == (3, 3)
    np.testing.assert_array_equal(state.data.reward, [0, 1, 2, 0, 0])
    state = add(state, _numbered(3, 3))  # slots 3,4,0: wraps and overwrites serial 0
    assert (int(state.position), int(state.size)) == (1, 5)
    np.testing.assert_array_equal(state.data.reward, [5, 1, 2, 3, 4])
    state = add(state, _numbered(6, 5))  # a full lap: slots 1,2,3,4,0
    assert (int(state.position), int(state.size)) == (1, 5)
    np.testing.assert_array_equal(state.data.reward, [10, 6, 7, 8, 9])
    # Every field of a slot belongs to the same transition.
    np.testing.assert_array_equal(state.data.obs[:, 3], state.data.reward)
    np.testing.assert_array_equal(state.data.action[:, 1], -state.data.reward)
    np.testing.assert_array_equal(state.data.advisor_action[:, 0], state.data.reward + 0.5)
    np.testing.assert_array_equal(state.data.next_obs[:, 0], state.data.reward + 1)
    np.testing.assert_array_equal(state.data.terminal, state.data.reward % 2)


def test_sampling_only_valid_slots_and_uniform():
    state = jax.jit(replay_add)(replay_init(100), _numbered(0, 7))
    batch = jax.jit(replay_sample, static_argnums=2)(state, jax.random.key(0), 7000)
    assert batch.obs.shape == (7000, 20) and batch.action.shape == (7000, 2)
    assert batch.reward.shape == (7000,) and batch.terminal.shape == (7000,)
    ids = np.asarray(batch.reward).astype(int)
    assert ids.min() == 0 and ids.max() == 6  # never an empty slot
    counts = np.bincount(ids, minlength=7)
    # Uniform: each count ~ Binomial(7000, 1/7), sd ≈ 29; 5 sd tolerance.
    assert np.all(np.abs(counts - 1000) < 150), counts
    np.testing.assert_array_equal(batch.obs[:, 0], batch.reward)  # rows gathered whole


def test_sample_empty_returns_zero_slot():
    batch = replay_sample(replay_init(4), jax.random.key(1), 3)
    assert batch.obs.shape == (3, 20)
    np.testing.assert_array_equal(batch.reward, 0.0)


def test_vmap_over_agents():
    @jax.jit
    def scenario(keys):
        states = jax.vmap(lambda _: replay_init(6))(keys)
        batches = jax.tree.map(lambda x: jnp.stack([x, x, x]), _numbered(0, 4))
        batches = batches.replace(reward=batches.reward + 10.0 * jnp.arange(3.0)[:, None])
        states = jax.vmap(replay_add)(states, batches)
        return states, jax.vmap(replay_sample, in_axes=(0, 0, None))(states, keys, 50)

    states, sampled = scenario(jax.random.split(jax.random.key(2), 3))
    np.testing.assert_array_equal(states.size, [4, 4, 4])
    np.testing.assert_array_equal(states.data.reward[2], [20, 21, 22, 23, 0, 0])
    assert sampled.reward.shape == (3, 50)
    for agent in range(3):
        valid = {10.0 * agent + i for i in range(4)}
        assert set(np.asarray(sampled.reward[agent]).tolist()) <= valid


def test_bad_input_errors():
    with pytest.raises(ValueError, match="capacity"):
        replay_init(0)
    with pytest.raises(ValueError, match="batch_size"):
        replay_sample(replay_init(4), jax.random.key(0), 0)
    with pytest.raises(ValueError, match="exceed the capacity 4"):
        replay_add(replay_init(4), _numbered(0, 5))
    bad = _numbered(0, 2).replace(obs=np.zeros((2, 19)))
    with pytest.raises(ValueError, match=r"batch\.obs has shape \(2, 19\)"):
        replay_add(replay_init(4), bad)
    bad = _numbered(0, 2).replace(reward=np.zeros(3))
    with pytest.raises(ValueError, match="batch.reward has 3 transitions"):
        replay_add(replay_init(4), bad)
