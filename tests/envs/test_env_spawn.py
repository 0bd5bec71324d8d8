"""Geometry, collision-free spawning over thousands of resets, and auto-reset."""

from __future__ import annotations

import math

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from envs import geometry, layouts

ALL = ("training", "validation", "physical", "procedural")


def test_box_sdf_hand_values():
    box = np.array([[0.0, 0.0, 1.0, 0.5, 0.0]])
    points = np.array([[2.0, 0.0], [2.0, 1.5], [0.0, 0.0], [0.5, 0.25], [1.0, 0.5]])
    expected = [1.0, math.sqrt(2.0), -0.5, -0.25, 0.0]
    np.testing.assert_allclose(geometry.box_sdf(points, box, xp=np)[:, 0], expected, atol=1e-12)
    jax_sdf = geometry.box_sdf(jnp.asarray(points), jnp.asarray(box))[:, 0]
    np.testing.assert_allclose(jax_sdf, expected, atol=1e-6)
    # Rotated a quarter turn, the box spans 0.5 in x and 1.0 in y.
    turned = np.array([[1.0, 1.0, 1.0, 0.5, math.pi / 2]])
    np.testing.assert_allclose(geometry.box_sdf(np.array([3.0, 1.0]), turned, xp=np), [1.5])
    np.testing.assert_allclose(geometry.box_sdf(np.array([1.0, 2.5]), turned, xp=np), [0.5])
    # A diamond (45°) with half extent 1: its vertex is √2 from the centre.
    diamond = np.array([[0.0, 0.0, 1.0, 1.0, math.pi / 4]])
    np.testing.assert_allclose(
        geometry.box_sdf(np.array([2.0, 0.0]), diamond, xp=np), [2.0 - math.sqrt(2.0)], atol=1e-12
    )
    assert geometry.footprint_collides(jnp.array([1.2, 0.0]), 0.22, jnp.asarray(box))
    assert not geometry.footprint_collides(jnp.array([1.3, 0.0]), 0.22, jnp.asarray(box))


def test_free_cells_are_entirely_clear():
    boxes = layouts.TRAINING.boxes
    required, cell = 0.42, 0.02
    cells = geometry.free_cells(boxes, layouts.ARENA_5M, required, cell)
    assert len(cells) > 1000
    offsets = np.array([[0, 0], [cell, 0], [0, cell], [cell, cell], [cell / 2, cell / 2]])
    points = (cells[:, None, :] + offsets[None]).reshape(-1, 2)
    clear = geometry.box_sdf(points.astype(np.float64), boxes.astype(np.float64), xp=np)
    assert clear.min() >= required - 1e-6


def test_goal_candidates_needed_hand_value():
    # 10,000 cells of 2 cm = 4 m²; a 1 m disk covers π/4 of it: ln(1e-15)/ln(0.785) = 142.7.
    assert geometry.goal_candidates_needed(10_000, 0.02, 1.0) == 143
    assert geometry.goal_candidates_needed(10_000, 0.02, 0.0) == 1


def test_rejection_sampler_falls_back_when_nothing_fits():
    boxes = jnp.asarray(layouts.walls((-1.0, 1.0, -1.0, 1.0)))
    kw = dict(radius=0.2, goal_clearance=0.0, min_goal_distance=0.5, n_candidates=64)
    ok = geometry.sample_spawn(
        jax.random.PRNGKey(0), boxes, (-1, 1, -1, 1), start_clearance=0.1, **kw
    )
    assert ok.valid
    assert geometry.clearance(ok.pose[:2], boxes) >= 0.3 - 1e-6
    # A 2 m room cannot give 1.5 m of clearance: the best candidate is used, flagged invalid.
    bad = geometry.sample_spawn(
        jax.random.PRNGKey(0), boxes, (-1, 1, -1, 1), start_clearance=1.5, **kw
    )
    assert not bad.valid
    assert np.all(np.isfinite(bad.pose))


@pytest.mark.parametrize("arena", ALL)
def test_thousands_of_resets_are_collision_free(sim, arena):
    env = sim.env(arena)
    cfg = env.config
    states = sim.many_resets(arena)
    n = len(states.obs)
    assert bool(jnp.all(states.spawn_valid))
    pose, goal = np.asarray(states.pose, np.float64), np.asarray(states.goal, np.float64)
    if env.procedural:
        boxes = np.asarray(states.layout, np.float64)  # [n, boxes, 5]
        start_clear = np.array(
            [geometry.box_sdf(p[:2], b, xp=np).min() for p, b in zip(pose, boxes, strict=True)]
        )
        goal_clear = np.array(
            [geometry.box_sdf(g, b, xp=np).min() for g, b in zip(goal, boxes, strict=True)]
        )
    else:
        boxes = env.layout_boxes().astype(np.float64)
        start_clear = geometry.box_sdf(pose[:, :2], boxes, xp=np).min(axis=-1)
        goal_clear = geometry.box_sdf(goal, boxes, xp=np).min(axis=-1)
    r = cfg.robot_radius
    assert start_clear.min() >= r + cfg.start_clearance - 1e-5
    assert goal_clear.min() >= r + cfg.goal_clearance - 1e-5
    assert np.linalg.norm(goal - pose[:, :2], axis=-1).min() >= cfg.min_goal_distance - 1e-5
    # The first observation: no collision at the start, at rest, goal far enough.
    obs = np.asarray(states.obs)
    assert obs[:, :16].min() > cfg.collision_distance + 0.05
    np.testing.assert_array_equal(obs[:, 18:], 0.0)
    assert np.all(~np.asarray(states.done)) and np.all(np.asarray(states.outcome) == 0)
    np.testing.assert_array_equal(states.reward, 0.0)
    np.testing.assert_array_equal(states.terminal_obs, states.obs)
    # Headings and positions spread over the arena, not a few fixed spots.
    assert pose[:, 2].min() < -3.0 and pose[:, 2].max() > 3.0
    xmin, xmax, ymin, ymax = env.bounds
    assert pose[:, 0].min() < xmin + 1.0 and pose[:, 0].max() > xmax - 1.0
    assert pose[:, 1].min() < ymin + 1.0 and pose[:, 1].max() > ymax - 1.0
    assert len(np.unique(np.round(pose[:, :2], 3), axis=0)) > 0.99 * n


def test_procedural_layouts_differ_and_park_unused_slots(sim):
    states = sim.many_resets("procedural")
    boxes = np.asarray(states.layout)
    n = len(boxes)
    assert boxes.shape == (n, 4 + layouts.PROCEDURAL_MAX, 5)
    active = np.asarray(layouts.procedural_active(jnp.asarray(boxes)))
    counts = active[:, 4:].sum(axis=1)
    assert counts.min() >= layouts.PROCEDURAL_MIN and counts.max() <= layouts.PROCEDURAL_MAX
    assert len(np.unique(counts)) == layouts.PROCEDURAL_MAX - layouts.PROCEDURAL_MIN + 1
    assert len(np.unique(boxes[:, 4, 0])) == n
    parked = boxes[:, 4:][~active[:, 4:]]
    assert np.all(parked[:, :2] >= layouts.PARK_XY - 1.0)  # far outside the 5 m arena


@pytest.mark.parametrize("arena", ["training", "procedural"])
def test_auto_reset_draws_a_fresh_start_and_goal(sim, arena):
    env = sim.env(arena)
    state = jax.tree_util.tree_map(lambda x: x[9], sim.many_resets(arena))
    # Force a timeout on the next step.
    state = state.replace(steps=jnp.int32(env.max_episode_steps - 1))
    out = sim.step_one(arena, state, (0.0, 0.0))
    assert out.done and out.outcome == 3
    assert not np.allclose(out.pose, state.pose) and not np.allclose(out.goal, state.goal)
    assert not np.array_equal(out.key, state.key)
    assert out.steps == 0 and out.spawn_valid
    np.testing.assert_allclose(
        out.obs, sim.first_obs(arena)(out.pose, out.goal, out.layout), atol=1e-6
    )
    # s' of the finished episode is the observation at the old pose, not the new one.
    np.testing.assert_allclose(out.terminal_obs[:16], state.obs[:16], atol=1e-5)
    if env.procedural:
        assert not np.allclose(out.layout, state.layout)
    # Stepping again continues the new episode: no replay of the first state.
    again = sim.step_one(arena, out, (0.0, 0.0))
    assert not again.done and again.steps == 1
    np.testing.assert_array_equal(again.terminal_obs, again.obs)
