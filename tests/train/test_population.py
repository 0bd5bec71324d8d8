"""vmap over seeds × hyperparameters equals separate runs; NaN isolation; episode logs."""

from __future__ import annotations

import jax
import numpy as np

import envs
from tests.train.conftest import GOOD, TINY, agent_slice


def _assert_same(a, b, what, atol=1e-5):
    """Integers exactly; floats to ``atol``.

    A vmapped matmul sums in another order than a lone one, so floats differ in the last
    bits, and Adam's g / (|g| + ε) turns a last-bit difference of a near-zero gradient into
    up to ~1 % of one learning-rate step. Parameters therefore get a tolerance of a few
    learning-rate steps; the discrete trajectory (outcomes, lengths, firing counts) must be
    identical, which it only is if every selector, noise and environment decision agreed.
    """
    leaves_a, tree_a = jax.tree_util.tree_flatten(a)
    leaves_b, tree_b = jax.tree_util.tree_flatten(b)
    assert tree_a == tree_b
    for x, y in zip(leaves_a, leaves_b, strict=True):
        x, y = np.asarray(x), np.asarray(y)
        if np.issubdtype(x.dtype, np.floating):
            np.testing.assert_allclose(x, y, rtol=1e-3, atol=atol, err_msg=what)
        else:
            np.testing.assert_array_equal(x, y, err_msg=what)


def test_vmapped_population_equals_single_runs(population, single_runs):
    state, _, _ = population
    for i, single in enumerate(single_runs):
        vm = agent_slice(state, i)
        _assert_same(vm.log, single.log, f"episode log of agent {i}")
        lr = 1e-3  # both learning rates of the population
        _assert_same(vm.learner, single.learner, f"learner of agent {i}", atol=0.3 * lr)
        assert int(vm.episodes) == int(single.episodes)
        assert int(vm.env_steps) == int(single.env_steps)


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


def test_frozen_agent_parameters_do_not_move(population):
    """After its N_total-th episode an agent is frozen: one more chunk changes nothing."""
    import jax.numpy as jnp

    from advisor_jax.run import population_functions

    state, hp, _ = population
    _, _, chunk_fn = population_functions(TINY)
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
