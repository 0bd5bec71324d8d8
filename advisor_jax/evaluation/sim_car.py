"""The car without a car: a simulated lidar, tracker, motors and clock for the runner's loop.

    advisor-jax-car POLICY_DIR --sim [--seed S] [--goal X Y] [--log FILE]

``SimulatedCar`` stands in for everything ``runner.loop.run_loop`` talks to, so the car's
own code runs unchanged: policy verification, the car's limits, the watchdog controller,
the drive model, the log (``--replay`` re-runs it bit for bit). It is the arena of
policy.json (``physical``: the 200-beam lidar)::

    latest() (lidar)     the env's 200 raw MuJoCo beams at the current pose, in the
                         RPLIDAR packages' format (quality, degrees clockwise, mm; 0 = none)
    latest() (tracker)   the pose (x, y, θ) stamped with the simulated time
    send(command)        the drive command, turned back into (V, ω) of the unicycle
    sleep(s)             advances the simulated time; each dt steps the env with the last
                         command (the env's own kinematics and sensors: ``NavEnv.step``)

Episodes end as on the car: the runner's controller stops at the goal (T_g) or at an
obstacle (min zone ≤ T_c), or after --max-cycles (default h_max). The NavEnv inside is
built so that it never ends an episode itself (no time limit, goal and collision
thresholds at zero): its auto-reset would move the car.
"""

from __future__ import annotations

import functools
import math
from collections.abc import Callable
from typing import NamedTuple

import jax
import jax.numpy as jnp
import numpy as np

import envs
from advisor_jax.runner.drive import AckermannCommand, DiffCommand, DiffDrive
from advisor_jax.runner.errors import RunnerError
from advisor_jax.runner.observation import Pose, Scan

NO_TIME_LIMIT = 2**31 - 1
RPLIDAR_QUALITY = 15.0  # a good reading's quality byte


def rplidar_scan(raw: np.ndarray, angle_cw: np.ndarray, stamp: float) -> Scan:
    """Raw MuJoCo rangefinder readings (m, −1 = no hit) as an RPLIDAR turn."""
    raw = np.asarray(raw, np.float64)
    mm = np.where(raw > 0, raw * 1000.0, 0.0)
    return Scan(np.stack([np.full_like(mm, RPLIDAR_QUALITY), angle_cw, mm], -1), stamp=stamp)


def lidar_angles_cw(env) -> np.ndarray:
    """The env's beam directions as the lidar reports them: degrees clockwise in [0, 360)."""
    return np.mod(-np.asarray(env.rig.directions_deg, np.float64), 360.0)


class SimulatedCar:
    """Lidar, tracker, motors and clock of ``run_loop`` in one simulated car (docstring)."""

    def __init__(self, policy, seed: int = 0):
        meta = policy.env
        # as the policy was trained
        sim = _simulator(meta["arena"], meta.get("motion", "kinematic"), policy.omega_max)
        env = sim.env
        if env.rig.kind != "lidar":
            raise ValueError(
                f"{policy.directory} was trained in the {meta['arena']!r} arena (16 sonar "
                "rays): the car, its closed loop and --sim drive lidar policies of the "
                "physical arena; export an agent trained with --preset physical"
            )
        if not 0 <= seed < 2**32:
            raise ValueError(f"--seed {seed}: a seed of the simulated episode is in [0, 2^32)")
        self.env, self.policy = env, policy
        # The drive model the runner converts (V, ω) with (``drive`` of the options, else a
        # differential drive as wide as the robot); ``send`` inverts it.
        self.drive = DiffDrive(track_width=2 * float(meta["robot_radius"]))
        self._readings, self._step = sim.readings, sim.step
        self._angles = lidar_angles_cw(env)
        self.state = sim.reset(jax.random.PRNGKey(seed))
        self.goal = tuple(float(g) for g in self.state.goal)
        self.t = 0.0  # the clock: simulated seconds
        self._t_env = 0.0  # time the env has been stepped to
        self._command: tuple[float, float] = (0.0, 0.0)  # (V m/s, ω rad/s)
        self.scans, self.poses = _Source(self.scan), _Source(self.pose)

    # -- the clock ---------------------------------------------------------------------
    def clock(self) -> float:
        return self.t

    def sleep(self, seconds: float) -> None:
        """Advances the time; the env moves one dt at a time under the last command."""
        self.t += max(seconds, 0.0)
        dt = self.env.config.dt
        while self._t_env + dt <= self.t + 1e-9:
            v, w = self._command
            action = jnp.array([v / self.policy.v_max, w / self.policy.omega_max], jnp.float32)
            self.state = self._step(self.state, action)
            self._t_env += dt
            if bool(self.state.done):  # only inside a box: the runner would have stopped
                raise RunnerError(
                    f"the simulated car drove into an obstacle at t = {self.t:.2f} s "
                    "(its collision stop did not fire)"
                )

    # -- the lidar and the tracker (``scans.latest()``, ``poses.latest()``) ----------------
    def scan(self) -> Scan:
        raw = np.asarray(self._readings(self.state.pose), np.float64)
        return rplidar_scan(raw, self._angles, stamp=self.t)

    def pose(self) -> Pose:
        x, y, theta = (float(v) for v in self.state.pose)
        return Pose(x, y, theta, t=self.t, stamp=self.t)

    # -- the motors ----------------------------------------------------------------------
    def send(self, command) -> None:
        self._command = unicycle(command, self.drive)

    def stop(self) -> None:
        self._command = (0.0, 0.0)

    def close(self) -> None:
        self.stop()


class _Simulator(NamedTuple):
    env: envs.NavEnv
    readings: Callable  # jit(env.sensor_readings)
    step: Callable  # jit(env.step)
    reset: Callable  # jit(env.reset)


@functools.lru_cache(maxsize=4)
def _simulator(arena: str, motion: str, omega_max: float) -> _Simulator:
    """The NavEnv of the simulated car and its jitted functions, built once per process
    for each (arena, motion, ω_max): cars of further seeds reuse the compiled programs."""
    env = envs.make_env(
        arena,
        motion=motion,
        omega_max=omega_max,
        max_episode_steps=NO_TIME_LIMIT,
        goal_tolerance=1e-9,  # the runner decides goal and collision, as on the car
        collision_distance=0.0,
        footprint_collision=False,
    )
    return _Simulator(env, jax.jit(env.sensor_readings), jax.jit(env.step), jax.jit(env.reset))


class _Source:
    """A ScanSource or PoseSource reading the simulated car."""

    def __init__(self, read):
        self.latest = read

    def close(self) -> None:
        pass


def unicycle(command, drive) -> tuple[float, float]:
    """(V, ω) that a drive command makes the simulated (unicycle) robot do."""
    if isinstance(command, DiffCommand):
        return (command.left + command.right) / 2, (
            command.right - command.left
        ) / drive.track_width
    if isinstance(command, AckermannCommand):
        return command.speed, command.speed * math.tan(command.steering) / drive.wheelbase
    raise TypeError(f"unknown drive command {command!r}")
