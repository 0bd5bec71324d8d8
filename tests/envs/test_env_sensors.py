"""MJX sensor readings equal CPU MuJoCo's; the arenas' MJCF loads in plain MuJoCo."""

from __future__ import annotations

import jax
import jax.numpy as jnp
import mujoco
import numpy as np
import pytest

from advisor_jax.contract import spec
from advisor_jax.contract.zones import reduce_to_zones
from envs import geometry, layouts, mjcf

FIXED = ("training", "validation", "physical")


def _free_poses(env, boxes: np.ndarray, n: int, seed: int) -> np.ndarray:
    """n random poses whose footprint does not overlap a box (numpy reference geometry)."""
    rng = np.random.default_rng(seed)
    xmin, xmax, ymin, ymax = env.bounds
    xy = rng.uniform([xmin, ymin], [xmax, ymax], size=(20 * n, 2))
    clear = geometry.box_sdf(xy, boxes.astype(np.float64), xp=np).min(axis=-1)
    xy = xy[clear > env.config.robot_radius][:n]
    assert len(xy) == n
    return np.concatenate([xy, rng.uniform(-np.pi, np.pi, (n, 1))], axis=1).astype(np.float32)


@pytest.mark.parametrize("arena", FIXED)
def test_mjx_readings_equal_cpu_mujoco(sim, arena):
    env = sim.env(arena)
    poses = _free_poses(env, env.layout_boxes(), 100, seed=1)
    layout = jnp.zeros((100, 0, 5))
    mjx_raw = np.asarray(sim.sensors(arena)(jnp.asarray(poses), layout))
    cpu_raw = np.stack([sim.cpu_readings(arena, p) for p in poses])
    assert mjx_raw.shape == (100, 200 if arena == "physical" else 16)
    np.testing.assert_allclose(mjx_raw, cpu_raw, atol=1e-4, rtol=0)
    # Walls enclose every arena: every ray hits something within its cutoff or reads −1.
    assert np.all((cpu_raw == -1.0) | ((cpu_raw > 0) & (cpu_raw <= env.rig.cutoff + 1e-6)))
    if arena == "physical":
        # The 16 zones: the env's jnp reduction vs the car's numpy one on CPU readings.
        prox = np.asarray(jax.jit(jax.vmap(env.proximity))(jnp.asarray(poses), layout))
        angles = np.radians(mjcf.lidar_beam_angles_deg(env.config.lidar_beams))
        ref = np.stack(
            [reduce_to_zones(angles, r, range_offset=env.config.robot_radius) for r in cpu_raw]
        )
        np.testing.assert_allclose(prox, ref, atol=1e-4, rtol=0)


def test_procedural_readings_equal_cpu_mujoco(sim):
    """Per-env boxes written into the batched MJX model match a CPU model of that layout."""
    env = sim.env("procedural")
    for seed in (3, 11):
        boxes = env.layout_boxes(jax.random.PRNGKey(seed))
        poses = _free_poses(env, boxes[layouts.procedural_active(boxes)], 50, seed=seed)
        layout = jnp.broadcast_to(jnp.asarray(boxes), (50, *boxes.shape))
        mjx_raw = np.asarray(sim.sensors("procedural")(jnp.asarray(poses), layout))
        model = mujoco.MjModel.from_xml_string(env.xml(boxes))
        data = mujoco.MjData(model)
        for pose, raw in zip(poses, mjx_raw, strict=True):
            data.qpos[:] = pose
            mujoco.mj_forward(model, data)
            np.testing.assert_allclose(raw, data.sensordata, atol=1e-4, rtol=0)


def test_sonar_geometry_follows_spec(sim):
    """Sites on the body circle at the mount angles, looking along the spec directions."""
    env = sim.env("training")
    model, data = env.mj_model, mujoco.MjData(env.mj_model)
    data.qpos[:] = [0.3, -0.2, 0.7]
    mujoco.mj_forward(model, data)
    for i, (direction, mount) in enumerate(
        zip(spec.SONAR_DIRECTIONS_DEG, spec.SONAR_MOUNTS_DEG, strict=True)
    ):
        site = model.site(f"range{i}").id
        a, m = np.radians(direction) + 0.7, np.radians(mount) + 0.7
        r = env.config.robot_radius
        np.testing.assert_allclose(
            data.site_xpos[site][:2], [0.3 + r * np.cos(m), -0.2 + r * np.sin(m)], atol=1e-6
        )
        np.testing.assert_allclose(
            data.site_xmat[site].reshape(3, 3)[:, 2], [np.cos(a), np.sin(a), 0], atol=1e-6
        )


def test_rays_see_neither_floor_nor_robot():
    """With no boxes at all, every horizontal ray misses: the floor and the robot's own
    sphere are invisible to it, so the readings are −1 (the env reads max_range)."""
    rig = mjcf.sonar_rig(0.22, 1.0)
    model = mujoco.MjModel.from_xml_string(
        mjcf.arena_xml(
            "empty",
            np.zeros((0, 5)),
            (-2.5, 2.5, -2.5, 2.5),
            rig,
            robot_radius=0.22,
            dt=0.05,
            n_walls=0,
        )
    )
    data = mujoco.MjData(model)
    for yaw in np.linspace(-np.pi, np.pi, 7):
        data.qpos[:] = [0.1, 0.2, yaw]
        mujoco.mj_forward(model, data)
        np.testing.assert_array_equal(data.sensordata, -1.0)


def test_programs_holding_the_sensors_trace_mjx_once(sim, monkeypatch):
    """MJX's sensor pass is one jitted function (``mjcf._sensor_pass``): a second program
    that reads the same arena's sensors at the same shapes reuses its trace (about a second
    on a CPU) and computes the same readings."""
    traces = []
    kinematics = mjcf.mjx.kinematics
    monkeypatch.setattr(mjcf.mjx, "kinematics", lambda m, d: traces.append(1) or kinematics(m, d))
    env = sim.env("training")
    poses = jnp.asarray(_free_poses(env, env.layout_boxes(), 3, seed=2))
    layout = jnp.zeros((3, 0, 5))
    first = jax.jit(jax.vmap(env.sensor_readings))(poses, layout)
    traced = len(traces)  # 0 where an earlier test's program traced it at these shapes
    assert traced <= 1
    second = jax.jit(jax.vmap(lambda p, b: env.sensor_readings(p, b) + 0.0))(poses, layout)
    assert len(traces) == traced
    np.testing.assert_array_equal(first, second)


@pytest.mark.parametrize("arena", (*FIXED, "procedural"))
def test_mjcf_file_loads_in_plain_mujoco(sim, arena, tmp_path):
    env = sim.env(arena)
    path = tmp_path / f"{arena}.xml"
    path.write_text(env.xml(env.layout_boxes(jax.random.PRNGKey(5))))
    model = mujoco.MjModel.from_xml_path(str(path))
    n_rays = 200 if arena == "physical" else 16
    assert model.nsensor == n_rays and model.nmat >= 1
    assert np.all(model.sensor_type == mujoco.mjtSensor.mjSENS_RANGEFINDER)
    assert model.opt.disableflags & mujoco.mjtDisableBit.mjDSBL_CONTACT
    np.testing.assert_array_equal(model.opt.gravity, 0.0)
    # Only ray-visible primitive types; the goal is no geom (nothing but floor, boxes, robot).
    visible = {mujoco.mjtGeom.mjGEOM_BOX, mujoco.mjtGeom.mjGEOM_PLANE, mujoco.mjtGeom.mjGEOM_SPHERE}
    assert set(model.geom_type.tolist()) <= {int(t) for t in visible}
    assert model.ngeom == 1 + len(env.layout_boxes()) + 1
    assert [model.joint(i).name for i in range(model.njnt)] == ["x", "y", "yaw"]
