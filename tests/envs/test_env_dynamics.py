"""Kinematics, reward (Eq. 8) and every termination on hand-placed poses.

Expected values are computed by hand from the training layout (``envs/layouts.py``):
obstacles west pillar x∈[-1.8,-1.2] y∈[0.3,1.3], north bar x∈[-0.3,0.7] y∈[1.3,1.8],
east pillar x∈[1.25,1.75] y∈[-0.8,0.4], south bar x∈[-1,0] y∈[-1.85,-1.35], walls at ±2.5.
The proximity readings P come from CPU MuJoCo at the hand-computed pose (reference).
"""

from __future__ import annotations

import math

import jax.numpy as jnp
import numpy as np
import pytest

from envs import geometry
from envs.navigation import COLLISION, GOAL, RUNNING, TIMEOUT

ARENA = "training"
DT, R = 0.05, 0.22


def _prox(sim, pose) -> np.ndarray:
    raw = sim.cpu_readings(ARENA, pose)
    return np.where(raw < 0, 1.0, np.minimum(raw, 1.0))


def _shaped(sim, pose0, pose1, goal) -> float:
    """k1 (d_{t-1} - d_t) + k2 (p_t - p_{t-1}), k1 = k2 = 5 (Table A3)."""
    d0 = math.dist(pose0[:2], goal)
    d1 = math.dist(pose1[:2], goal)
    p0, p1 = _prox(sim, pose0).min(), _prox(sim, pose1).min()
    return 5.0 * (d0 - d1) + 5.0 * (p1 - p0)


def test_free_move_reward_and_observation(sim):
    goal = (0.0, -1.0)
    state = sim.place(ARENA, (0.0, 0.0, 0.0), goal, steps=4)
    out = sim.step_one(ARENA, state, (1.0, 0.0))
    pose1 = (0.05, 0.0, 0.0)  # V = 1 m/s for 0.05 s straight ahead
    np.testing.assert_allclose(out.pose, pose1, atol=1e-6)
    expected = _shaped(sim, (0.0, 0.0, 0.0), pose1, goal)
    np.testing.assert_allclose(out.reward, expected, atol=1e-4)
    obs = np.asarray(out.obs)
    np.testing.assert_allclose(obs[:16], _prox(sim, pose1), atol=1e-4)
    np.testing.assert_allclose(obs[16], math.atan2(-1.0, -0.05), atol=1e-5)  # δ, CCW
    np.testing.assert_allclose(obs[17], math.hypot(0.05, 1.0), atol=1e-5)  # d
    np.testing.assert_allclose(obs[18:], (1.0, 0.0), atol=1e-5)  # world-frame velocity
    assert not out.done and out.outcome == RUNNING and not out.terminal
    np.testing.assert_array_equal(out.terminal_obs, out.obs)
    assert out.steps == 5
    np.testing.assert_allclose(out.running_return, 1.5 + expected, atol=1e-4)


def test_turning_move_follows_the_arc_midpoint(sim):
    state = sim.place(ARENA, (0.0, 0.0, 0.5), (2.0, 2.0))
    out = sim.step_one(ARENA, state, (0.5, 0.5))  # V = 0.5 m/s, ω = 0.5 · 3 rad/s
    w = 0.5 * sim.env(ARENA).config.omega_max
    mid = 0.5 + 0.5 * w * DT
    expected = (0.5 * DT * math.cos(mid), 0.5 * DT * math.sin(mid), 0.5 + w * DT)
    np.testing.assert_allclose(out.pose, expected, atol=1e-6)
    np.testing.assert_allclose(out.obs[18:], np.array(expected[:2]) / DT, atol=1e-5)


def test_goal_reached(sim):
    state = sim.place(ARENA, (0.0, 0.0, 0.0), (0.19, 0.0), steps=7)
    out = sim.step_one(ARENA, state, (1.0, 0.0))  # d: 0.19 → 0.14 ≤ T_g = 0.15
    assert out.done and out.terminal and out.outcome == GOAL
    np.testing.assert_allclose(out.reward, 10.0)
    assert out.episode_length == 8
    np.testing.assert_allclose(out.episode_return, 1.5 + 10.0, atol=1e-6)
    np.testing.assert_allclose(out.terminal_obs[17], 0.14, atol=1e-5)
    # Auto-reset: the new episode's first observation, at rest, from a fresh spawn.
    assert out.steps == 0 and out.running_return == 0.0
    np.testing.assert_array_equal(out.obs[18:], 0.0)
    fresh = sim.first_obs(ARENA)(out.pose, out.goal, out.layout)
    np.testing.assert_allclose(out.obs, fresh, atol=1e-6)
    assert not np.allclose(out.obs, out.terminal_obs)


def test_collision_by_the_sensor_rule(sim):
    # East wall face at x = 2.5. After the move the centre is at 2.21: the footprint clears
    # the wall by 0.07 m, so only the sonars (≈0.075 m ahead) can call it a collision.
    state = sim.place(ARENA, (2.16, 0.0, 0.0), (-1.0, 0.0), steps=5)
    state = state.replace(speeds=jnp.array([0.2, 0.4, 0.6], jnp.float32))
    assert _prox(sim, (2.21, 0.0, 0.0)).min() <= 0.1
    assert not geometry.footprint_collides(jnp.array([2.21, 0.0]), R, sim.env(ARENA)._boxes)
    out = sim.step_one(ARENA, state, (1.0, 0.0))
    assert out.done and out.terminal and out.outcome == COLLISION
    np.testing.assert_allclose(out.reward, -10.0)
    np.testing.assert_allclose(out.collision_speed, (0.4 + 0.6 + 1.0) / 3, atol=1e-6)
    assert out.episode_length == 6


def test_collision_by_footprint_between_two_rays(sim):
    # The east pillar's corner (1.25, 0.4) pokes 5 mm into the robot's right side (body
    # angle -90°, between the two side sonars that both look to -90°). No sonar reads
    # ≤ T_c there; the footprint check must catch it.
    corner, depth = np.array([1.25, 0.4]), 0.215
    xy = corner + depth * np.array([-1.0, 1.0]) / math.sqrt(2.0)
    pose = (float(xy[0]), float(xy[1]), math.pi / 4)
    assert _prox(sim, pose).min() > 0.1
    state = sim.place(ARENA, pose, (-1.0, -1.0), steps=3)
    out = sim.step_one(ARENA, state, (0.0, 0.0))
    assert out.done and out.terminal and out.outcome == COLLISION
    np.testing.assert_allclose(out.reward, -10.0)


def test_goal_wins_over_a_collision_in_the_same_step(sim):
    state = sim.place(ARENA, (2.16, 0.0, 0.0), (2.21, 0.0), steps=5)
    out = sim.step_one(ARENA, state, (1.0, 0.0))
    assert _prox(sim, (2.21, 0.0, 0.0)).min() <= 0.1  # would be a collision
    assert out.outcome == GOAL and out.terminal
    np.testing.assert_allclose(out.reward, 10.0)


def test_timeout_is_a_truncation(sim):
    h_max = sim.env(ARENA).max_episode_steps
    assert h_max == 300
    goal = (-1.5, -0.5)
    state = sim.place(ARENA, (0.0, 0.0, 0.0), goal, steps=h_max - 1)
    out = sim.step_one(ARENA, state, (1.0, 0.0))
    assert out.done and not out.terminal and out.outcome == TIMEOUT
    expected = _shaped(sim, (0.0, 0.0, 0.0), (0.05, 0.0, 0.0), goal)  # no special reward
    np.testing.assert_allclose(out.reward, expected, atol=1e-4)
    assert out.episode_length == h_max
    np.testing.assert_allclose(out.terminal_obs[:2], _prox(sim, (0.05, 0.0, 0.0))[:2], atol=1e-4)


@pytest.mark.parametrize("bad", [(np.nan, 0.3), (0.5, np.inf)])
def test_non_finite_action_under_jit_stops_and_flags(sim, bad):
    state = sim.place(ARENA, (0.0, 0.0, 0.3), (1.0, 1.0), steps=2)
    out = sim.step_one(ARENA, state, bad)
    assert out.invalid_action
    np.testing.assert_allclose(out.pose, state.pose, atol=1e-7)
    np.testing.assert_array_equal(out.obs[18:], 0.0)
    assert np.all(np.isfinite(out.obs)) and np.isfinite(out.reward)
    ok = sim.step_one(ARENA, state, (0.0, 0.0))
    assert not ok.invalid_action


def test_actions_are_clipped_to_the_box(sim):
    state = sim.place(ARENA, (0.0, 0.0, 0.0), (1.0, 1.0))
    a = sim.step_one(ARENA, state, (5.0, -7.0))
    b = sim.step_one(ARENA, state, (1.0, -1.0))
    np.testing.assert_allclose(a.pose, b.pose, atol=1e-7)
