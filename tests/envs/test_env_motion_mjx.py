"""The ``mjx`` motion model (envs/motion.py): the simulated P3DX obeys its limits, its
MJX steps equal CPU MuJoCo's, collisions end episodes as before, the sensors still match
CPU MuJoCo in every arena, vmap of N envs equals N lone envs, and the motion setting
round-trips. The ``kinematic`` model's own tests (the other files here) are untouched.

Expected limits are hand-computed from ``DriveParams()``: m = 9 kg, I = 0.26 kg m², b =
0.33 m, r = 0.0975 m, 12.3 rad/s per wheel (1.19925 m/s at the rim), 0.6 N m per wheel
(6.1538 N): a_max = 2 F / m = 1.3675 m/s², yaw acceleration F b / I = 7.8107 rad/s²; the
default ω_max of the model is 5 rad/s.
"""

from __future__ import annotations

import contextlib
import dataclasses
import io
import math

import jax
import jax.numpy as jnp
import mujoco
import numpy as np
import pytest

with contextlib.redirect_stdout(io.StringIO()):  # MJX's "Failed to import warp" notice
    import envs
from envs import geometry
from envs.motion import DEFAULT_OMEGA_MAX, DriveParams, parse_motion
from envs.navigation import COLLISION, GOAL

DT = 0.05
A_MAX, YAW_ACC_MAX, RIM_MAX = 2 * 0.6 / 0.0975 / 9.0, 0.6 / 0.0975 * 0.33 / 0.26, 12.3 * 0.0975
ARENAS = ("training", "validation", "physical", "procedural")


class MjxSim:
    """``motion="mjx"`` environments and their jitted functions, built once per module."""

    def __init__(self):
        self._memo = {}

    def _once(self, key, build):
        if key not in self._memo:
            self._memo[key] = build()
        return self._memo[key]

    def env(self, arena: str = "training"):
        return self._once(("env", arena), lambda: envs.make_env(arena, motion="mjx"))

    def resets(self, arena: str = "training", n: int = 16):
        env = self.env(arena)
        keys = jax.random.split(jax.random.PRNGKey(5), n)
        return self._once(("resets", arena, n), lambda: jax.jit(jax.vmap(env.reset))(keys))

    def step(self, arena: str = "training"):
        """(NavState [B], actions [B, 2]) -> NavState [B]."""
        env = self.env(arena)
        return self._once(("step", arena), lambda: jax.jit(jax.vmap(env.step)))

    def rollout(self, arena: str = "training"):
        """(NavState [B], actions [T, B, 2]) -> NavState [T, B] after each step."""
        step = jax.vmap(self.env(arena).step)

        def run(state, actions):
            return jax.lax.scan(lambda s, a: (step(s, a),) * 2, state, actions)[1]

        return self._once(("rollout", arena), lambda: jax.jit(run))

    def observe(self, arena: str = "training"):
        """(poses [B, 3], goals [B, 2], velocities [B, 2]) -> observations [B, 20], the
        sensors read at each pose (jitted: eagerly, MJX's ray casts compile op by op)."""
        env = self.env(arena)

        def observe(pose, goal, velocity):
            return env.observe(pose, goal, env.proximity(pose), velocity)

        return self._once(("observe", arena), lambda: jax.jit(jax.vmap(observe)))

    def place(self, pose, goal, qvel=(0.0, 0.0, 0.0), steps: int = 0, arena: str = "training"):
        """A batch of one state: the robot at ``pose`` moving with ``qvel``, mid-episode."""
        base = jax.tree_util.tree_map(lambda x: x[:1], self.resets(arena))
        pose, goal = jnp.asarray([pose], jnp.float32), jnp.asarray([goal], jnp.float32)
        velocity = jnp.asarray([qvel[:2]], jnp.float32)
        obs = self.observe(arena)(pose, goal, velocity)
        return base.replace(
            pose=pose,
            goal=goal,
            qvel=jnp.asarray([qvel], jnp.float32),
            obs=obs,
            terminal_obs=obs,
            steps=jnp.asarray([steps], jnp.int32),
            speeds=jnp.zeros((1, 3), jnp.float32),
        )


@pytest.fixture(scope="module")
def msim() -> MjxSim:
    return MjxSim()


def _drive(msim, state, actions, horizon: int = 40):
    """Applies ``actions`` [T ≤ horizon, 2] to a batch-of-one state; returns the T states
    after (padded to one horizon, so that every call shares one compiled rollout)."""
    t = len(actions)
    padded = np.zeros((horizon, 1, 2), np.float32)
    padded[:t, 0] = actions
    out = msim.rollout()(state, jnp.asarray(padded))
    return jax.tree_util.tree_map(lambda x: np.asarray(x[:t, 0]), out)


def _body_speeds(qvel, pose):
    """Forward speed and yaw rate of each state from its world-frame qvel and heading."""
    forward = qvel[:, 0] * np.cos(pose[:, 2]) + qvel[:, 1] * np.sin(pose[:, 2])
    return forward, qvel[:, 2]


def test_straight_line_acceleration_and_top_speed(msim):
    # Full throttle from rest in open floor, goal far ahead: the speed rises by a_max per
    # second (the servo saturates at its torque limit) and settles at V_max = 1 m/s.
    state = msim.place((-1.8, -0.5, 0.0), (2.0, -0.5))
    out = _drive(msim, state, [(1.0, 0.0)] * 40)
    assert not out.done.any()
    forward, yaw = _body_speeds(out.qvel, out.pose)
    np.testing.assert_allclose(yaw, 0.0, atol=1e-6)
    gains = np.diff(np.concatenate([[0.0], forward]))
    assert np.all(gains <= A_MAX * DT * (1 + 1e-4))
    np.testing.assert_allclose(gains[:6], A_MAX * DT, rtol=1e-3)  # torque-limited phase
    np.testing.assert_allclose(forward[-1], 1.0, atol=1e-4)
    assert np.all(np.linalg.norm(out.qvel[:, :2], axis=1) <= 1.0 + 1e-5)
    # The observation's velocity is the step's displacement / dt, the collision speed's too.
    disp = np.diff(np.concatenate([[[-1.8, -0.5]], out.pose[:, :2]]), axis=0) / DT
    np.testing.assert_allclose(out.obs[:, 18:], disp, atol=2e-4)
    np.testing.assert_allclose(out.speeds[:, -1], np.linalg.norm(disp, axis=1), atol=2e-4)


def test_braking_is_torque_limited_too(msim):
    state = msim.place((-1.8, -0.5, 0.0), (2.0, -0.5), qvel=(1.0, 0.0, 0.0))
    out = _drive(msim, state, [(0.0, 0.0)] * 20)
    forward, _ = _body_speeds(out.qvel, out.pose)
    losses = np.diff(np.concatenate([[1.0], forward]))
    assert np.all(losses >= -A_MAX * DT * (1 + 1e-4))
    np.testing.assert_allclose(losses[:10], -A_MAX * DT, rtol=1e-3)
    np.testing.assert_allclose(forward[-1], 0.0, atol=1e-4)  # stopped, not reversing
    stop = 1.0 / (2 * A_MAX)  # v² / 2a = 0.366 m of braking distance
    np.testing.assert_allclose(out.pose[-1, 0] - (-1.8), stop, atol=0.03)


def test_spin_on_the_spot_reaches_omega_max_at_the_yaw_acceleration_limit(msim):
    state = msim.place((0.0, 0.0, 0.0), (2.0, 0.0))
    out = _drive(msim, state, [(0.0, 1.0)] * 20)  # ω = 1 · 5 rad/s: wheels at ∓0.825 m/s
    forward, yaw = _body_speeds(out.qvel, out.pose)
    np.testing.assert_allclose(forward, 0.0, atol=1e-5)
    np.testing.assert_allclose(out.pose[:, :2], 0.0, atol=1e-5)
    gains = np.diff(np.concatenate([[0.0], yaw]))
    assert np.all(gains <= YAW_ACC_MAX * DT * (1 + 1e-4))
    np.testing.assert_allclose(gains[:10], YAW_ACC_MAX * DT, rtol=1e-3)
    np.testing.assert_allclose(yaw[-1], DEFAULT_OMEGA_MAX["mjx"], atol=1e-3)


def test_full_speed_full_turn_is_limited_by_the_wheels(msim):
    # (V, ω) = (1 m/s, 5 rad/s) asks the outer wheel for 1 + 0.825 m/s; it stops at the rim
    # limit 1.19925, the inner wheel runs at 0.175: V = 0.687 m/s, ω = 3.104 rad/s.
    state = msim.place((0.0, 0.0, 0.0), (2.0, 0.0))
    out = _drive(msim, state, [(1.0, 1.0)] * 30)
    forward, yaw = _body_speeds(out.qvel, out.pose)
    inner = 1.0 - 5.0 * 0.165
    np.testing.assert_allclose(forward[-1], (RIM_MAX + inner) / 2, atol=2e-3)
    np.testing.assert_allclose(yaw[-1], (RIM_MAX - inner) / 0.33, atol=1e-2)
    # No side slip: the velocity points along the heading, up to the turn of the last
    # physics step h = 0.01 s (the side grip removes that in the next one): |v| sin(ω h).
    side = -out.qvel[:, 0] * np.sin(out.pose[:, 2]) + out.qvel[:, 1] * np.cos(out.pose[:, 2])
    turn = np.abs(forward) * np.sin(np.abs(yaw) * DT / 5)
    assert np.all(np.abs(side) <= turn * 1.01 + 1e-5)


def test_random_actions_never_break_a_limit(msim):
    env = msim.env()
    states = msim.resets()
    actions = jax.random.uniform(
        jax.random.PRNGKey(1), (40, 16, 2), minval=jnp.array([0.0, -1.0]), maxval=1.0
    )
    out = jax.tree_util.tree_map(np.asarray, msim.rollout()(states, actions))
    prev = np.concatenate([np.asarray(states.qvel)[None], out.qvel[:-1]])
    # Steps that neither ended an episode (the state is then the next one's start) nor
    # began one (its start is the previous state).
    moving = ~out.done & ~np.concatenate([np.zeros((1, 16), bool), out.done[:-1]])
    speed = np.linalg.norm(out.qvel[..., :2], axis=-1)
    assert np.all(speed <= env.config.v_max + 1e-5)
    assert np.all(np.linalg.norm(out.obs[..., 18:], axis=-1) <= env.config.v_max + 1e-5)
    b2 = 0.165
    fwd = lambda q, th: q[..., 0] * np.cos(th) + q[..., 1] * np.sin(th)  # noqa: E731
    heading = out.pose[..., 2]
    wheels = np.stack([fwd(out.qvel, heading) - b2 * out.qvel[..., 2],
                       fwd(out.qvel, heading) + b2 * out.qvel[..., 2]])  # fmt: skip
    assert np.all(np.abs(wheels[:, moving]) <= RIM_MAX + 1e-4)
    dv = np.linalg.norm(out.qvel[..., :2] - prev[..., :2], axis=-1)[moving]
    dw = np.abs(out.qvel[..., 2] - prev[..., 2])[moving]
    # |Δv| ≤ a_max dt plus the turn of the velocity vector (|ω| ≤ 7.3 rad/s); |Δω| exact.
    assert np.all(dv <= A_MAX * DT + speed[moving] * 7.3 * DT + 1e-4)
    assert np.all(dw <= YAW_ACC_MAX * DT * (1 + 1e-4))
    assert out.done.any()


def test_mjx_steps_equal_cpu_mujoco(msim):
    """One control step = ``substeps`` MJX steps of the robot-only model; the arena's own
    MJCF (robot, actuators, boxes, sensors) stepped by CPU MuJoCo gives the same motion."""
    env = msim.env()
    drive = env.drive
    model = mujoco.MjModel.from_xml_string(env.xml())
    data = mujoco.MjData(model)
    rng = np.random.default_rng(0)
    move = jax.jit(drive.move)
    for _ in range(5):
        pose = np.array([*rng.uniform(-1, 1, 2), rng.uniform(-3, 3)])
        qvel = np.array([*rng.uniform(-0.7, 0.7, 2), rng.uniform(-4, 4)])
        v, w = rng.uniform(0, 1), rng.uniform(-5, 5)
        data.qpos[:], data.qvel[:] = pose, qvel
        data.ctrl[:] = np.asarray(drive.wheel_targets(jnp.float32(v), jnp.float32(w)))
        start = data.qpos[:2].copy()
        for _ in range(env.config.drive.substeps):
            mujoco.mj_step(model, data)
        got_pose, got_velocity, got_qvel = move(
            jnp.float32(pose), jnp.float32(qvel), jnp.float32(v), jnp.float32(w)
        )
        want_heading = (data.qpos[2] + np.pi) % (2 * np.pi) - np.pi
        np.testing.assert_allclose(got_pose, [*data.qpos[:2], want_heading], atol=1e-5)
        np.testing.assert_allclose(got_qvel, data.qvel, atol=1e-4)
        np.testing.assert_allclose(got_velocity, (data.qpos[:2] - start) / DT, atol=1e-4)


@pytest.mark.parametrize("arena", ARENAS)
def test_sensors_match_cpu_mujoco(msim, arena):
    """At 16 spawn poses of each arena, turned and shifted a little, the MJX readings of
    the ``mjx`` model equal CPU MuJoCo's ``mj_forward`` on the same MJCF (which holds the
    robot's mass, wheel sites and actuators besides today's sensors)."""
    env = msim.env(arena)
    states = jax.tree_util.tree_map(np.asarray, msim.resets(arena))
    rng = np.random.default_rng(3)
    poses = states.pose + rng.uniform([-0.05, -0.05, -3], [0.05, 0.05, 3], (16, 3))
    mjx_raw = np.asarray(
        jax.jit(jax.vmap(env.sensor_readings))(jnp.float32(poses), jnp.asarray(states.layout))
    )
    model = mujoco.MjModel.from_xml_string(env.xml())
    assert model.nu == 3 and model.nsensor == (200 if arena == "physical" else 16)
    for pose, layout, raw in zip(poses, states.layout, mjx_raw, strict=True):
        if env.procedural:
            model = mujoco.MjModel.from_xml_string(env.xml(layout))
        data = mujoco.MjData(model)
        data.qpos[:] = np.float32(pose)
        mujoco.mj_forward(model, data)
        np.testing.assert_allclose(raw, data.sensordata, atol=1e-4, rtol=0)


def test_collision_ends_the_episode_at_the_body_speed(msim):
    # Heading for the east wall (x = 2.5) at 0.8 m/s, braking hard: the sensor rule fires
    # (min P ≤ T_c) before the footprint touches; the collision speed is the body's.
    state = msim.place((2.17, 0.0, 0.0), (-1.0, 0.0), qvel=(0.8, 0.0, 0.0), steps=5)
    out = _drive(msim, state, [(0.0, 0.0)])
    assert out.done[0] and out.terminal[0] and out.outcome[0] == COLLISION
    np.testing.assert_allclose(out.reward[0], -10.0)
    moved = out.terminal_obs[0, 18]  # the step's mean speed, straight ahead
    # Braking at a_max over 5 physics steps of h = 0.01 s (semi-implicit Euler: the
    # position moves with each step's new speed): 0.8 − a h (1 + … + 5) / 5.
    np.testing.assert_allclose(moved, 0.8 - A_MAX * 0.01 * 3, atol=1e-4)
    assert 2.17 + moved * DT > 2.5 - 0.22 - 0.1  # the front sonar reads ≤ T_c
    np.testing.assert_allclose(out.collision_speed[0], moved / 3, atol=1e-5)  # 2 steps at 0
    assert out.episode_length[0] == 6
    # Auto-reset: the fresh episode starts at rest.
    np.testing.assert_array_equal(out.qvel[0], 0.0)
    np.testing.assert_array_equal(out.obs[0, 18:], 0.0)


def test_footprint_collision_and_goal_still_end_episodes(msim):
    env = msim.env()
    corner, depth = np.array([1.25, 0.4]), 0.215  # the east pillar's corner, as in
    xy = corner + depth * np.array([-1.0, 1.0]) / math.sqrt(2.0)  # test_env_dynamics
    assert geometry.footprint_collides(jnp.asarray(xy), 0.22, jnp.asarray(env.layout_boxes()))
    out = _drive(msim, msim.place((*xy, math.pi / 4), (-1.0, -1.0)), [(0.0, 0.0)])
    assert out.outcome[0] == COLLISION
    out = _drive(msim, msim.place((0.0, 0.0, 0.0), (0.16, 0.0), qvel=(0.5, 0.0, 0.0)), [(0.5, 0)])
    assert out.outcome[0] == GOAL and out.terminal[0]


def test_vmapped_mjx_step_equals_lone_steps(msim, arena="procedural"):
    """Six envs, random actions, steps forced near the timeout so that auto-resets happen:
    the batched step equals six lone ``env.step`` calls field by field. In the procedural
    arena, whose per-env model (boxes) and spawns are the most that vmap can get wrong."""
    env = msim.env(arena)
    lone = jax.jit(env.step)
    states = jax.tree_util.tree_map(lambda x: x[:6], msim.resets(arena))
    h = env.max_episode_steps
    states = states.replace(steps=jnp.array([0, h - 2, h - 1, 10, h - 3, h - 1], jnp.int32))
    actions = jax.random.uniform(
        jax.random.PRNGKey(4), (3, 6, 2), minval=jnp.array([0.0, -1.0]), maxval=1.0
    )
    batched = states
    single = [jax.tree_util.tree_map(lambda x, i=i: x[i], states) for i in range(6)]
    for t in range(3):
        batched = msim.step(arena)(batched, actions[t])
        single = [lone(s, actions[t, i]) for i, s in enumerate(single)]
        stacked = jax.tree_util.tree_map(lambda *xs: jnp.stack(xs), *single)
        for name in ("obs", "terminal_obs", "reward", "pose", "qvel", "goal", "layout"):
            np.testing.assert_allclose(
                getattr(batched, name), getattr(stacked, name), atol=1e-5, err_msg=name
            )
        for name in ("done", "terminal", "outcome", "steps", "key"):
            np.testing.assert_array_equal(
                getattr(batched, name), getattr(stacked, name), err_msg=name
            )
    assert bool(jnp.any(batched.done))


def test_motion_settings_round_trip_and_the_kinematic_default():
    assert envs.EnvConfig().motion == "kinematic" and envs.EnvConfig().omega_max == 3.0
    assert envs.EnvConfig(motion="mjx").omega_max == 5.0
    for setting in ("kinematic", "mjx", "kinematic:omega_max=2", "mjx:omega_max=4,substeps=10"):
        cfg = envs.EnvConfig(**parse_motion(setting))
        assert cfg.motion_setting == setting
    cfg = envs.EnvConfig(**parse_motion("mjx:wheel_torque_max=0.5"))
    assert cfg.drive == dataclasses.replace(DriveParams(), wheel_torque_max=0.5)
    for bad, words in (
        ("car", "unknown motion model"),
        ("kinematic:mass=3", "KEY one of omega_max"),
        ("mjx:mass=-1", "finite and positive"),
        ("mjx:substeps=1", "raise substeps"),
    ):
        with pytest.raises(ValueError, match=words):
            envs.make_env("training", motion=bad)


def test_kinematic_state_and_model_carry_no_drive(msim):
    kinematic = envs.make_env("training")
    assert kinematic.drive is None and "<actuator>" not in kinematic.xml()
    state = jax.jit(kinematic.reset)(jax.random.PRNGKey(0))
    assert state.qvel.shape == (0,)
    assert msim.resets().qvel.shape == (16, 3)
    assert kinematic.metadata()["motion"] == "kinematic"
    assert msim.env().metadata()["motion"] == "mjx"
