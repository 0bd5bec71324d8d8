"""Batched evaluation, the ``advisor-jax arena``/``evaluate`` CLI, and bad-input errors."""

from __future__ import annotations

import json
import math

import jax
import jax.numpy as jnp
import mujoco
import numpy as np
import pytest

import envs
from advisor_jax.cli import main as cli
from advisor_jax.evaluation.evaluate import (
    EvalMetrics,
    collision_speed_sd,
    make_evaluate,
    mean_collision_speed,
    success_rate,
    summary,
    timeout_rate,
)
from envs.navigation import COLLISION, GOAL, TIMEOUT, EnvConfig

H = 12  # a short h_max keeps the evaluation compile small


def test_metric_helpers_hand_values():
    m = EvalMetrics(
        outcome=jnp.array([GOAL, COLLISION, TIMEOUT, GOAL, COLLISION]),
        length=jnp.array([10, 20, 300, 30, 40]),
        episode_return=jnp.zeros(5),
        collision_speed=jnp.array([9.0, 0.4, 9.0, 9.0, 0.6]),
    )
    np.testing.assert_allclose([m.success_rate, m.collision_rate, m.timeout_rate], [0.4, 0.4, 0.2])
    np.testing.assert_allclose(m.mean_collision_speed, 0.5)  # only collision episodes count
    np.testing.assert_allclose(collision_speed_sd(m), 0.1, rtol=1e-5)  # 0.4, 0.6 about 0.5
    assert summary(m)["collision_speed_sd"] == pytest.approx(0.1, rel=1e-5)
    assert summary(m.replace(outcome=jnp.full(5, GOAL)))["collision_speed_sd"] is None
    assert math.isnan(float(collision_speed_sd(m.replace(outcome=jnp.full(5, GOAL)), math.nan)))
    none = m.replace(outcome=jnp.array([GOAL, TIMEOUT, GOAL, GOAL, TIMEOUT]))
    assert (
        float(mean_collision_speed(none)) == 0.0 and summary(none)["mean_collision_speed"] is None
    )
    assert math.isnan(float(mean_collision_speed(none, empty=float("nan"))))
    grad = jax.grad(lambda s: mean_collision_speed(none.replace(collision_speed=s)))(jnp.ones(5))
    assert np.all(np.isfinite(grad))


@pytest.fixture(scope="module")
def short_env():
    return envs.make_env("training", max_episode_steps=H)


def test_evaluate_keeps_the_first_episode_and_vmaps_over_params(short_env):
    """Policy (V, ω) = (p, p / 2): p = 0 never moves (all timeouts at H, return 0); p = 1
    drives circles. vmap over p equals a plain per-step reference loop."""
    episodes = 16

    def policy(p, obs):
        return jnp.stack([p, 0.5 * p])

    evaluate_fn = make_evaluate(short_env, policy, episodes)
    key = jax.random.PRNGKey(4)
    both = jax.jit(jax.vmap(evaluate_fn, in_axes=(0, None)))(jnp.array([0.0, 1.0]), key)
    assert both.outcome.shape == (2, episodes)

    still = jax.tree_util.tree_map(lambda x: x[0], both)
    np.testing.assert_array_equal(still.outcome, TIMEOUT)
    np.testing.assert_array_equal(still.length, H)
    np.testing.assert_allclose(still.episode_return, 0.0, atol=1e-5)
    assert float(success_rate(still)) == 0.0 and float(timeout_rate(still)) == 1.0

    # Reference: step all envs H times, record each env's first finished episode by hand.
    states = jax.jit(jax.vmap(short_env.reset))(jax.random.split(key, episodes))
    step = jax.jit(jax.vmap(short_env.step))
    first = {}
    for _ in range(H):
        states = step(states, jnp.tile(jnp.array([1.0, 0.5]), (episodes, 1)))
        for i in np.flatnonzero(np.asarray(states.done)):
            first.setdefault(i, (int(states.outcome[i]), int(states.episode_length[i])))
    moving = jax.tree_util.tree_map(lambda x: x[1], both)
    assert sorted(first) == list(range(episodes))
    np.testing.assert_array_equal(moving.outcome, [first[i][0] for i in range(episodes)])
    np.testing.assert_array_equal(moving.length, [first[i][1] for i in range(episodes)])


def test_make_evaluate_rejects_bad_episode_counts(short_env):
    with pytest.raises(ValueError, match="episodes"):
        make_evaluate(short_env, lambda p, o: o[:2], 0)


# ---- CLI ------------------------------------------------------------------------------


def _run(argv, capsys):
    try:
        cli.main(argv)
        code = 0
    except SystemExit as exit_:
        code = exit_.code
    out = capsys.readouterr()
    return code, out.out, out.err


def test_cli_arena_writes_loadable_xml(tmp_path, capsys):
    path = tmp_path / "training.xml"
    code, _, _ = _run(["arena", "training", "--xml", str(path)], capsys)
    assert code == 0
    model = mujoco.MjModel.from_xml_path(str(path))
    assert model.nsensor == 16


def test_cli_procedural_seed_is_the_first_episode_layout(sim, tmp_path, capsys):
    path = tmp_path / "p.xml"
    assert _run(["arena", "procedural", "--seed", "3", "--xml", str(path)], capsys)[0] == 0
    model = mujoco.MjModel.from_xml_path(str(path))
    first = sim.many_resets("procedural").layout[0]  # of reset(PRNGKey(3)), see conftest
    for i, (cx, cy, hx, hy, _) in enumerate(np.asarray(first)):
        geom = model.geom(f"box{i}")
        np.testing.assert_allclose(geom.pos[:2], (cx, cy), atol=1e-5)
        np.testing.assert_allclose(geom.size[:2], (hx, hy), atol=1e-5)


def test_cli_creates_missing_directories(tmp_path, capsys):
    target = tmp_path / "new" / "dir" / "arena.xml"
    assert _run(["arena", "training", "--xml", str(target)], capsys)[0] == 0
    assert mujoco.MjModel.from_xml_path(str(target)).nsensor == 16
    assert [p.name for p in target.parent.iterdir()] == ["arena.xml"]  # no temporary left


def test_cli_unwritable_path_is_a_one_line_error(tmp_path, capsys):
    blocker = tmp_path / "a_file"
    blocker.write_text("not a directory")
    target = blocker / "arena.xml"
    code, out, err = _run(["arena", "training", "--xml", str(target)], capsys)
    assert code == 2 and out == ""
    lines = [line for line in err.splitlines() if line.strip()]
    assert lines[-1] == f"error: cannot write {target}: {blocker} is not a directory"
    assert "Traceback" not in err


@pytest.mark.parametrize(
    ("argv", "needle"),
    [
        (["arena", "nowhere", "--xml", "x.xml"], "unknown arena 'nowhere'"),
        (["evaluate", "--policy", "oracle"], "unknown policy 'oracle'"),
        (["evaluate", "--episodes", "0"], "--episodes must be a positive integer"),
    ],
)
def test_cli_bad_values_exit_2_with_a_message(argv, needle, capsys):
    code, _, err = _run(argv, capsys)
    assert code == 2 and needle in err and "Traceback" not in err
    if "arena" in needle:
        assert "training, validation, physical, procedural" in err


def test_cli_evaluate_json(capsys):
    code, out, _ = _run(["evaluate", "--arena", "training", "--episodes", "8", "--json"], capsys)
    assert code == 0
    result = json.loads(out)
    assert result["episodes"] == 8 and result["policy"] == "advisor"
    total = result["success_rate"] + result["collision_rate"] + result["timeout_rate"]
    assert total == pytest.approx(1.0)


def test_cli_help_lists_subcommands(capsys):
    code, out, _ = _run(["--help"], capsys)
    assert code == 0 and "arena" in out and "evaluate" in out


# ---- bad input ------------------------------------------------------------------------


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
