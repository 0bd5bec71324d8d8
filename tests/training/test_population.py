"""vmap over seeds × hyperparameters equals separate runs; NaN isolation; episode logs."""

from __future__ import annotations

import dataclasses

import jax
import numpy as np
import pytest

import envs
from advisor_jax.training.population import agent_keys
from advisor_jax.training.program import population_functions
from tests.compare import assert_same_agent
from tests.training.conftest import GOOD, TINY, agent_slice, run_chunks


def _assert_same(a, b, what):
    """Bit-identical: the same code path run twice (used for frozen agents)."""
    for x, y in zip(jax.tree_util.tree_leaves(a), jax.tree_util.tree_leaves(b), strict=True):
        np.testing.assert_array_equal(np.asarray(x), np.asarray(y), err_msg=what)


def _check_against_single_runs(state, initial, single_runs):
    """Every healthy agent of ``state`` equals its lone run (``assert_same_training``)."""
    for i, single in enumerate(single_runs):
        assert_same_agent(agent_slice(state, i), single, agent_slice(initial, i), i)


def test_vmapped_population_equals_single_runs(population, initial_state, single_runs):
    _check_against_single_runs(population[0], initial_state, single_runs)


def test_the_check_catches_a_broken_vmap(population, initial_state, single_runs, tiny_functions):
    """The comparison above fails for the two ways a vmap can mix agents up.

    Swapped hyperparameters (agents 0 and 2 share seed 0 and differ only in β) leave the
    discrete trajectory of these tiny runs identical, so only the parameter bound can catch
    them; a reused key changes the episodes themselves.
    """
    _, init_fn, chunk_fn = tiny_functions
    _, hp, seeds = population
    swapped = jax.tree_util.tree_map(lambda x: x[np.array([2, 1, 0, 3, 4])], hp)
    keys = agent_keys(seeds)
    reused = keys.at[1].set(keys[0])  # agent 1 draws agent 0's randomness
    for label, run_hp, run_keys in (("swapped β", swapped, keys), ("reused key", hp, reused)):
        broken = jax.device_get(run_chunks(init_fn, chunk_fn, run_keys, run_hp))
        with pytest.raises(AssertionError):
            _check_against_single_runs(broken, initial_state, single_runs)
        print(f"{label}: caught")


def test_snapshot_is_the_actor_a_shorter_run_ends_with(population):
    """TINY keeps each agent's actor of episode 2 (of 3): it equals the final actor of the
    same agents trained for 2 episodes, a separately compiled program. Close, not
    bit-identical: the two programs may round differently on another CPU."""
    state, hp, seeds = population
    _, init_fn, chunk_fn = population_functions(
        dataclasses.replace(TINY, episodes=2, snapshot_episodes=())
    )
    short = jax.device_get(run_chunks(init_fn, chunk_fn, agent_keys(seeds), hp))
    assert np.all(state.snapshots.taken[:GOOD, 0]) and not np.any(state.snapshots.diverged[:GOOD])
    final_moved = 0.0
    for snap, two, final in zip(
        *(jax.tree_util.tree_leaves(t)
          for t in (state.snapshots.actor, short.learner.actor, state.learner.actor)),
        strict=True,
    ):  # fmt: skip
        snap, two = np.asarray(snap)[:GOOD, 0], np.asarray(two)[:GOOD]
        scale = np.abs(two).max()
        np.testing.assert_allclose(snap, two, rtol=1e-4, atol=1e-4 * scale)
        final_moved = max(final_moved, np.abs(np.asarray(final)[:GOOD] - snap).max() / scale)
    assert final_moved > 1e-2  # the third episode's updates: the check can tell them apart


def test_grid_points_differ(population):
    # Agents 0 and 2 share seed 0 but differ in beta: same start, different learning.
    state, hp, seeds = population
    assert seeds[0] == seeds[2] and float(hp.beta[0]) != float(hp.beta[2])
    a0, a2 = agent_slice(state.learner.actor, 0), agent_slice(state.learner.actor, 2)
    diff = jax.tree_util.tree_map(lambda x, y: float(np.max(np.abs(x - y))), a0, a2)
    assert max(jax.tree_util.tree_leaves(diff)) > 0


def test_nan_agent_is_frozen_and_isolated(population):
    state, _, _ = population
    diverged = np.asarray(state.diverged)
    assert diverged[GOOD], "the agent with lr_critic=1e38 must be flagged"
    assert not diverged[:GOOD].any()
    for i in range(GOOD):
        for leaf in jax.tree_util.tree_leaves(agent_slice(state.learner, i)):
            assert np.all(np.isfinite(leaf))


def test_episode_logs_are_consistent(population):
    state, _, _ = population
    n_total = TINY.episodes
    for i in range(GOOD):
        log = agent_slice(state.log, i)
        done = min(int(state.episodes[i]), n_total)
        assert done == n_total, "tiny runs are sized so that every agent finishes"
        assert set(np.unique(log.outcome)) <= {envs.GOAL, envs.COLLISION, envs.TIMEOUT}
        assert np.all(log.length >= 1) and np.all(log.length <= TINY.max_episode_steps)
        assert np.all(log.actor_steps <= log.length) and np.all(log.actor_steps >= 0)
        # Inactive agents stop counting: the logged episodes used exactly env_steps steps
        # (one env per agent, the last episode ends the budget).
        assert int(log.length.sum()) == int(state.env_steps[i])
        collided = log.outcome == envs.COLLISION
        assert np.all(np.isfinite(log.collision_speed[collided]))
        assert np.all(np.isnan(log.collision_speed[~collided]))


def test_frozen_agent_parameters_do_not_move(population, tiny_functions):
    """After its N_total-th episode an agent is frozen: one more chunk changes nothing."""
    import jax.numpy as jnp

    state, hp, _ = population
    _, _, chunk_fn = tiny_functions
    before = jax.device_get(state.learner)
    after, _ = chunk_fn(jax.tree_util.tree_map(jnp.asarray, state), hp, jnp.int32(10_000))
    after = jax.device_get(after)
    for i in range(GOOD):
        _assert_same(agent_slice(after.learner.actor, i), agent_slice(before.actor, i), "actor")
        _assert_same(
            agent_slice(after.learner.target_critic, i),
            agent_slice(before.target_critic, i),
            "target critic",
        )
        np.testing.assert_array_equal(after.log.outcome[i], state.log.outcome[i])
