"""The advisor inside the env (sign conventions, a closed-loop run) and vmap == per-env."""

from __future__ import annotations

import math

import jax
import jax.numpy as jnp
import numpy as np

from advisor_jax.agent.advisor import advisor_action, arena_advisor
from envs.navigation import GOAL

ARENA = "training"


def test_obstacle_on_the_left_turns_right(sim):
    # Heading +x at y = 0.95 under the north bar (y ≥ 1.3, x ∈ [-0.3, 0.7]): the bar is
    # 0.13 m to the left of the body; nothing else is within T_o on the right.
    env = sim.env(ARENA)
    obs = sim.first_obs(ARENA)(
        jnp.array([0.2, 0.95, 0.0]), jnp.array([2.0, 0.95]), jnp.zeros((0, 5))
    )
    assert obs[0] < env.obstacle_threshold  # sensor 1 looks left
    v, omega = np.asarray(advisor_action(obs, arena_advisor(env)))
    assert omega < 0 and v < 1.0
    # And the env turns the robot clockwise for ω < 0.
    state = sim.place(ARENA, (0.2, 0.95, 0.0), (2.0, 0.95))
    out = sim.step_one(ARENA, state, (v, omega))
    assert out.pose[2] < 0.0


def test_goal_on_the_left_turns_left(sim):
    env = sim.env(ARENA)
    obs = sim.first_obs(ARENA)(jnp.array([0.0, 0.0, 0.0]), jnp.array([0.0, 0.9]), jnp.zeros((0, 5)))
    assert np.min(obs[:16]) > env.obstacle_threshold  # goal-reaching mode
    np.testing.assert_allclose(obs[16], math.pi / 2, atol=1e-5)
    v, omega = np.asarray(advisor_action(obs, arena_advisor(env)))
    np.testing.assert_allclose(omega, math.tanh(math.pi / 2), atol=1e-5)  # Eq. (9)
    np.testing.assert_allclose(v, 1.0 - math.exp(-5.0 * 0.9), atol=1e-5)  # Eq. (10)


def test_advisor_reaches_an_open_goal_in_closed_loop(sim):
    """Facing away from a goal 1 m off in open floor, the advisor turns and gets there."""
    env = sim.env(ARENA)
    state = sim.place(ARENA, (0.0, 0.0, math.pi), (0.8, 0.6))
    for _ in range(80):
        action = advisor_action(state.obs, arena_advisor(env))
        state = sim.step_one(ARENA, state, action)
        if state.done:
            break
    assert state.done and state.outcome == GOAL
    assert 20 < state.episode_length < 80


def test_vmapped_step_equals_per_env_step(sim):
    """Eight envs, random actions, a few steps with timeouts and collisions forcing
    auto-resets: the batched step equals eight lone ``env.step`` calls field by field."""
    env = sim.env(ARENA)
    lone_step = jax.jit(env.step)
    states = jax.tree_util.tree_map(lambda x: x[:8], sim.many_resets(ARENA))
    states = states.replace(steps=jnp.array([0, 298, 299, 150, 0, 297, 10, 299], jnp.int32))
    actions = jax.random.uniform(
        jax.random.PRNGKey(3), (4, 8, 2), minval=jnp.array([0.0, -1.0]), maxval=1.0
    )
    batched, single = (
        states,
        [jax.tree_util.tree_map(lambda x, i=i: x[i], states) for i in range(8)],
    )
    any_done = False
    for t in range(4):
        batched = sim.step(ARENA)(batched, actions[t])
        single = [lone_step(s, actions[t, i]) for i, s in enumerate(single)]
        stacked = jax.tree_util.tree_map(lambda *xs: jnp.stack(xs), *single)
        for name in ("obs", "terminal_obs", "reward", "pose", "goal", "key", "episode_return"):
            np.testing.assert_allclose(
                getattr(batched, name), getattr(stacked, name), atol=1e-5, err_msg=name
            )
        for name in ("done", "terminal", "outcome", "steps", "episode_length"):
            np.testing.assert_array_equal(
                getattr(batched, name), getattr(stacked, name), err_msg=name
            )
        any_done |= bool(jnp.any(batched.done))
    assert any_done
