"""The arenas as brax envs: brax's own wrappers take them, and they step the NavEnv itself.

The `training` arena with h_max 12, compiled once per module.
Spinning in place (a = (-1, 1): V = 0, ω = ω_max) never ends an episode, so the time limit
is EpisodeWrapper's truncation; driving straight ahead ends one by a collision.
"""

from __future__ import annotations

import contextlib
import io

import jax
import jax.numpy as jnp
import numpy as np
import pytest
from brax.envs.base import Env
from brax.envs.wrappers.training import AutoResetWrapper, EpisodeWrapper, VmapWrapper

with contextlib.redirect_stdout(io.StringIO()):  # MJX's "Failed to import warp" notice
    import envs
from envs.brax_env import NO_TIME_LIMIT, to_nav_action, wrap_for_training

H = 12
N = 4
SPIN = jnp.tile(jnp.array([-1.0, 1.0]), (N, 1))  # V = 0, ω = ω_max: never ends an episode
AHEAD = jnp.tile(jnp.array([1.0, 0.0]), (N, 1))  # full speed straight: into a wall


@pytest.fixture(scope="module")
def brax_env():
    return envs.make_brax_env("training", max_episode_steps=H, omega_max=2.0)


@pytest.fixture(scope="module")
def brax_wrapped(brax_env):
    """brax's own training wrappers, jitted once."""
    env = AutoResetWrapper(EpisodeWrapper(VmapWrapper(brax_env), brax_env.episode_length, 1))
    return env, jax.jit(env.reset), jax.jit(env.step)


def test_is_a_brax_env_of_the_arena(brax_env):
    assert isinstance(brax_env, Env)
    assert (brax_env.observation_size, brax_env.action_size) == (20, 2)
    assert brax_env.episode_length == H and brax_env.backend == "mjx"
    nav = brax_env.nav  # make_env's arguments reach the NavEnv; its own time limit is off
    assert nav.config.omega_max == 2.0 and nav.max_episode_steps == NO_TIME_LIMIT
    assert envs.make_brax_env("physical").episode_length == 150  # the arena's h_max


def test_action_mapping_is_brax_box_to_the_arena_box():
    a = jnp.array([[-1.0, -1.0], [0.0, 0.5], [1.0, 1.0]])
    np.testing.assert_allclose(to_nav_action(a), [[0.0, -1.0], [0.5, 0.5], [1.0, 1.0]])


def test_step_is_the_navenv_step(brax_env):
    """The same function, not a copy: BraxNavEnv.step's state is NavEnv.step's on the
    mapped action, bit for bit."""
    key = jax.random.PRNGKey(3)
    state = jax.jit(brax_env.reset)(key)  # jitted: an eager reset compiles op by op
    nav_state = jax.jit(brax_env.nav.reset)(key)
    action = jnp.array([0.4, -0.3])
    after = jax.jit(brax_env.step)(state, action)
    expected = jax.jit(brax_env.nav.step)(nav_state, to_nav_action(action))
    for got, want in zip(jax.tree.leaves(after.pipeline_state), jax.tree.leaves(expected),
                         strict=True):  # fmt: skip
        np.testing.assert_array_equal(got, want)
    np.testing.assert_array_equal(after.obs, expected.obs)
    assert float(after.reward) == float(expected.reward)


def test_brax_wrappers_truncate_and_replay_the_first_state(brax_wrapped):
    """EpisodeWrapper ends a spinning episode at h_max as a truncation (done 1, truncation
    1, no termination); AutoResetWrapper then puts back the first observation."""
    _, reset, step = brax_wrapped
    state = reset(jax.random.split(jax.random.PRNGKey(0), N))
    first = np.asarray(state.obs)
    for t in range(1, H + 1):
        state = step(state, SPIN)
        done = np.asarray(state.done)
        assert (done == 1).all() if t == H else (done == 0).all(), t
    np.testing.assert_array_equal(state.info["truncation"], np.ones(N))
    np.testing.assert_array_equal(state.obs, first)
    assert (np.asarray(state.metrics["goal"]) == 0).all()


def test_termination_is_done_without_truncation(brax_wrapped):
    _, reset, step = brax_wrapped
    state = reset(jax.random.split(jax.random.PRNGKey(1), N))
    ended = np.zeros(N, bool)
    for _ in range(H):
        state = step(state, AHEAD)
        done = np.asarray(state.done) == 1
        early = done & (np.asarray(state.info["truncation"]) == 0)
        hit = np.asarray(state.metrics["goal"]) + np.asarray(state.metrics["collision"])
        np.testing.assert_array_equal(hit[early], 1.0)  # a termination is a goal or collision
        ended |= early
    assert ended.any(), "full speed ahead hits something within h_max in some env"


def test_fresh_auto_reset_draws_a_new_start_after_a_truncation(brax_env):
    """wrap_for_training (what the brax agents train with): after a truncation each env
    starts a new episode, not the first one again."""
    env = wrap_for_training(brax_env, episode_length=H)
    state = jax.jit(env.reset)(jax.random.split(jax.random.PRNGKey(2), N))
    first_pose = np.asarray(state.pipeline_state.pose)
    step = jax.jit(env.step)
    for _ in range(H):
        state = step(state, SPIN)
    assert (np.asarray(state.done) == 1).all()
    pose = np.asarray(state.pipeline_state.pose)
    assert not np.allclose(pose[:, :2], first_pose[:, :2])
    np.testing.assert_array_equal(state.obs, state.pipeline_state.obs)
    state = step(state, SPIN)  # the new episode's first step: counting starts again
    np.testing.assert_array_equal(state.info["steps"], np.ones(N))


def test_the_mjx_robot_is_a_brax_env_too():
    """``motion`` reaches the NavEnv inside: the calibrated arena's robot under brax's
    wrappers, stepping like the NavEnv it wraps."""
    env = envs.make_brax_env("training", motion="mjx", max_episode_steps=H)
    assert env.nav.config.motion == "mjx"
    state = jax.jit(env.reset)(jax.random.PRNGKey(0))
    nav_state = jax.jit(env.nav.step)(state.pipeline_state, to_nav_action(AHEAD[0]))
    stepped = jax.jit(env.step)(state, AHEAD[0])
    np.testing.assert_array_equal(stepped.obs, nav_state.obs)
