"""Arena construction: bad configurations named, eager checks, each arena's description,
and a procedural layout drawn by ``layout_boxes`` equal to the one ``reset`` draws."""

from __future__ import annotations

import json

import jax
import numpy as np
import pytest

import envs
from advisor_jax.training.population import seed_key
from envs.navigation import EnvConfig


def test_layout_boxes_is_the_first_episodes_layout(sim):
    """What ``advisor-jax arena procedural --seed 3`` writes is the layout of
    ``reset(PRNGKey(3))`` (``seed_key(3)`` is that key)."""
    first = sim.many_resets("procedural").layout[0]  # of reset(PRNGKey(3)), see conftest
    drawn = sim.env("procedural").layout_boxes(seed_key(3))
    np.testing.assert_array_equal(np.asarray(drawn), np.asarray(first))


def test_unknown_arena_lists_the_valid_names():
    with pytest.raises(ValueError, match="training, validation, physical, procedural"):
        envs.make_env("mars")


def test_unknown_config_field_is_named():
    with pytest.raises(ValueError, match="omega"):
        envs.make_env("training", omega=2.0)


@pytest.mark.parametrize(
    ("field", "value"),
    [
        ("dt", 0.0),
        ("robot_radius", -0.22),
        ("max_range", float("nan")),
        ("omega_max", float("inf")),
        ("max_episode_steps", -1),
        ("spawn_candidates", 0),
        ("lidar_beams", 8),
        ("collision_distance", 2.0),
        ("goal_tolerance", "0.15"),
    ],
)
def test_bad_config_values_name_field_and_value(field, value):
    with pytest.raises(ValueError, match=field):
        EnvConfig(**{field: value})


def test_eager_non_finite_action_raises(sim):
    env = sim.env("training")
    state = jax.tree_util.tree_map(lambda x: x[0], sim.many_resets("training"))
    with pytest.raises(ValueError, match="non-finite action.*nan"):
        env.step(state, np.array([np.nan, 0.0], np.float32))
    with pytest.raises(ValueError, match="shape"):
        env.step(state, np.zeros(3, np.float32))


@pytest.mark.parametrize(
    ("arena", "h_max", "t_o", "sensor"),
    [
        ("training", 300, 0.5, "sonar"),
        ("validation", 300, 0.5, "sonar"),
        ("physical", 150, 0.6, "lidar"),
        ("procedural", 300, 0.5, "sonar"),
    ],
)
def test_arena_description(sim, arena, h_max, t_o, sensor):
    env = sim.env(arena)
    assert (env.observation_size, env.action_size) == (20, 2)
    assert env.max_episode_steps == h_max and env.obstacle_threshold == t_o
    meta = json.loads(json.dumps(env.metadata()))
    assert meta["sensor"] == sensor and meta["h_max"] == h_max and meta["T_o"] == t_o
    assert (meta["T_g"], meta["T_c"], meta["dt"], meta["max_range"]) == (0.15, 0.1, 0.05, 1.0)
    assert meta["bounds"] == list(env.bounds)
    if sensor == "lidar":
        beams = np.array(meta["lidar_beams_deg"])
        assert len(beams) == 200 and meta["lidar_range_offset"] == env.config.robot_radius
        # No beam on a zone boundary (multiples of 22.5°): at least a quarter step away.
        gap = np.abs((beams + 11.25) % 22.5 - 11.25)
        assert gap.min() >= 0.45 - 1e-9
        assert meta["lidar_cutoff"] == pytest.approx(1.0 + env.config.robot_radius)
    else:
        assert meta["sonar_directions_deg"][0] == 90.0 and len(meta["sonar_mounts_deg"]) == 16
    assert envs.make_env(arena, max_episode_steps=40).max_episode_steps == 40
