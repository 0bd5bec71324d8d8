"""Closed-loop check: the numpy car runner drives an exported policy in the simulator.

The runner (``advisor_jax.runner``) never sees JAX observations. Each control period it
gets what the car would get: a lidar turn in the RPLIDAR packages' format (quality, angle
in degrees *clockwise*, distance in mm, 0 = invalid) made from the simulated ``physical``
arena's 200 raw MuJoCo rangefinder beams, and the tracked pose (x, y, θ, t). It builds the
observation itself (zone reduction, finite-difference velocity, goal angle and distance),
runs the numpy MLP and returns (V m/s, ω rad/s) through the watchdog ``Controller``; the
simulator applies that command. Episodes start from the same keys as the JAX evaluation
of the same policy (``evaluate.make_evaluate``), so the two success rates are paired::

    for each episode key:  state = env.reset(key)
        repeat until done:  scan, pose ← sim;  (V, ω) ← Controller.cycle(scan, pose)
                            state ← env.step(state, (V / v_max, ω / ω_max))
"""

from __future__ import annotations

import dataclasses
import math

import jax
import jax.numpy as jnp
import numpy as np

import envs
from advisor_jax.agent.networks import make_actor
from advisor_jax.deploy.export import actor_params_from_policy
from advisor_jax.evaluation import evaluate
from advisor_jax.evaluation.sim_car import lidar_angles_cw, rplidar_scan
from advisor_jax.runner.drive import DiffDrive
from advisor_jax.runner.loop import RUN, Controller, LoopConfig
from advisor_jax.runner.observation import ObservationBuilder, ObservationConfig, Pose
from advisor_jax.runner.policy import Policy


@dataclasses.dataclass
class ClosedLoopResult:
    runner_outcomes: np.ndarray  # [episodes] envs outcome codes with the runner driving
    jax_outcomes: np.ndarray  # [episodes] JAX evaluation of the same policy, same episodes
    stops: int  # watchdog stop commands issued by the runner (should be 0 in simulation)

    @property
    def runner_success(self) -> float:
        return float(np.mean(self.runner_outcomes == envs.GOAL))

    @property
    def jax_success(self) -> float:
        return float(np.mean(self.jax_outcomes == envs.GOAL))

    @property
    def agreement(self) -> float:
        """Fraction of episodes that ended with the same outcome both ways."""
        return float(np.mean(self.runner_outcomes == self.jax_outcomes))


def run_closed_loop(policy: Policy, episodes: int, key: jax.Array) -> ClosedLoopResult:
    """Runner-in-the-loop and JAX evaluation of ``policy`` on the same ``episodes``."""
    meta = policy.env
    motion = meta.get("motion", "kinematic")  # exports before the motion models: kinematic
    omega = {} if "omega_max" in envs.parse_motion(motion) else {"omega_max": policy.omega_max}
    env = envs.make_env(meta["arena"], motion=motion, max_episode_steps=meta["h_max"], **omega)
    if env.rig.kind != "lidar":
        raise ValueError(
            f"{policy.directory} was trained in the {meta['arena']!r} arena (16 sonar rays): "
            "the car and its closed loop drive lidar policies of the physical arena; export "
            "an agent trained with --preset physical"
        )
    params, hidden = actor_params_from_policy(policy)
    evaluate_fn = evaluate.make_evaluate(env, make_actor(hidden).apply, episodes)
    jax_outcomes = np.asarray(jax.jit(evaluate_fn)(params, key).outcome)

    readings = jax.jit(env.sensor_readings)
    reset, step = jax.jit(env.reset), jax.jit(env.step)
    angle_cw = lidar_angles_cw(env)
    obs_cfg = ObservationConfig(
        max_range=policy.max_range, range_offset=policy.range_offset, bounds=policy.bounds
    )
    loop_cfg = LoopConfig(rate_hz=1.0 / policy.dt)
    drive = DiffDrive(track_width=2 * meta["robot_radius"])
    outcomes, stops = np.zeros(episodes, np.int32), 0
    for i, episode_key in enumerate(jax.random.split(key, episodes)):
        state = reset(episode_key)
        builder = ObservationBuilder(obs_cfg, tuple(float(g) for g in state.goal))
        controller = Controller(policy, builder, drive, loop_cfg)
        for t in range(env.max_episode_steps):
            now = t * policy.dt
            scan = rplidar_scan(readings(state.pose), angle_cw, stamp=now)
            x, y, theta = (float(v) for v in state.pose)
            result = controller.cycle(now, scan, Pose(x, y, theta, t=now, stamp=now))
            if result.state == RUN:
                v, w = result.physical
                action = jnp.array([v / policy.v_max, w / policy.omega_max], jnp.float32)
            else:
                stops += 1
                action = jnp.zeros(2, jnp.float32)
            state = step(state, action)
            if bool(state.done):
                outcomes[i] = int(state.outcome)
                break
    return ClosedLoopResult(runner_outcomes=outcomes, jax_outcomes=jax_outcomes, stops=stops)


def binomial_ci95(p: float, n: int) -> float:
    """Half-width of the normal-approximation 95 % interval of a success rate."""
    return 1.96 * math.sqrt(max(p * (1 - p), 1e-12) / n)
