"""What an arena step works with: its settings (``EnvConfig``), its state (``NavState``)
and the outcome codes of an episode. Defaults are the paper's (Tables A1-A3) or documented
in docs/architecture.md, "Environment"."""

from __future__ import annotations

import dataclasses
import math

import jax
from flax import struct

from advisor_jax.contract import spec
from envs.motion import DEFAULT_OMEGA_MAX, MOTION_MODELS, DriveParams, motion_setting

# Outcome codes of an episode (NavState.outcome).
RUNNING, GOAL, COLLISION, TIMEOUT = 0, 1, 2, 3
OUTCOME_NAMES = ("running", "goal", "collision", "timeout")
OMEGA_MAX = DEFAULT_OMEGA_MAX["kinematic"]  # rad/s; the paper leaves ω_max open
SPEED_HISTORY = 3  # steps averaged for the collision speed
SPAWN_CELL = 0.02  # m, grid of the fixed arenas' free-cell spawn tables


@dataclasses.dataclass(frozen=True)
class EnvConfig:
    """Static environment settings; defaults are the paper's (Tables A1-A3) or documented."""

    dt: float = spec.CONTROL_DT  # s, control period (V-REP's default step)
    v_max: float = spec.V_MAX  # m/s, V = a0 · v_max
    omega_max: float | None = None  # rad/s, ω = a1 · omega_max; None → the motion model's
    # default (motion.DEFAULT_OMEGA_MAX: not in the paper; calibrated)
    max_range: float = spec.MAX_RANGE  # m, sensor cutoff; "no hit" reads this
    robot_radius: float = 0.22  # m, round P3DX-like footprint
    max_episode_steps: int = 0  # h_max; 0 → the arena's default (300, physical 150)
    goal_tolerance: float = 0.15  # T_g, m
    collision_distance: float = 0.1  # T_c, m
    goal_reward: float = 10.0  # c1
    collision_penalty: float = 10.0  # c2 (the reward is -c2)
    k_distance: float = 5.0  # k1
    k_proximity: float = 5.0  # k2
    min_goal_distance: float = 1.0  # m, start-goal separation at spawn
    start_clearance: float = 0.2  # m, free distance around the footprint at the start
    goal_clearance: float = 0.1  # m, free distance around a footprint centred on the goal
    spawn_candidates: int = 64  # candidates per spawn (first valid wins)
    lidar_beams: int = 200  # physical arena's lidar
    footprint_collision: bool = True  # geometric collision check besides the sensor rule
    motion: str = "kinematic"  # "kinematic" (unicycle) or "mjx" (simulated P3DX; motion.py)
    drive: DriveParams = DriveParams()  # the "mjx" model's robot (ignored by "kinematic")

    def __post_init__(self):
        if self.motion not in MOTION_MODELS:
            raise ValueError(
                f"EnvConfig.motion={self.motion!r} is not a motion model; choose one of "
                f"{', '.join(MOTION_MODELS)}"
            )
        if self.omega_max is None:  # frozen: resolve the default once, here
            object.__setattr__(self, "omega_max", DEFAULT_OMEGA_MAX[self.motion])
        positive = ("dt", "v_max", "omega_max", "max_range", "robot_radius", "goal_tolerance")
        non_negative = (
            "collision_distance", "goal_reward", "collision_penalty", "k_distance",
            "k_proximity", "min_goal_distance", "start_clearance", "goal_clearance",
        )  # fmt: skip
        for name in positive + non_negative:
            value = getattr(self, name)
            if isinstance(value, bool) or not isinstance(value, int | float):
                raise ValueError(f"EnvConfig.{name} must be a number, got {value!r}")
            if not math.isfinite(value) or value < 0 or (name in positive and value == 0):
                kind = "positive" if name in positive else "non-negative"
                raise ValueError(f"EnvConfig.{name} must be finite and {kind}, got {value}")
        for name, low in (("max_episode_steps", 0), ("spawn_candidates", 1), ("lidar_beams", 16)):
            value = getattr(self, name)
            if isinstance(value, bool) or not isinstance(value, int) or value < low:
                raise ValueError(f"EnvConfig.{name} must be an integer >= {low}, got {value!r}")
        if self.collision_distance >= self.max_range:
            raise ValueError(
                f"EnvConfig.collision_distance={self.collision_distance} must be below "
                f"max_range={self.max_range}"
            )
        if not isinstance(self.drive, DriveParams):
            raise ValueError(f"EnvConfig.drive must be a DriveParams, got {self.drive!r}")
        if self.motion == "mjx":
            self.drive.check_step(self.dt)

    @property
    def motion_setting(self) -> str:
        """The motion model with its non-default parameters, e.g. ``"mjx"`` or
        ``"mjx:wheel_torque_max=0.5"``: what ``envs.make_env(arena, motion=...)`` takes back."""
        return motion_setting(self.motion, self.drive, self.omega_max)


@struct.dataclass
class NavState:
    """State of one environment (all fields per env; vmap adds a leading axis)."""

    obs: jax.Array  # [20] current observation (after auto-reset: the new episode's first)
    reward: jax.Array  # () f32, of the last step
    done: jax.Array  # () bool, the last step ended an episode
    terminal: jax.Array  # () bool, ended by goal or collision (no bootstrap)
    outcome: jax.Array  # () int32, outcome of the episode the last step ended, 0 if none
    terminal_obs: jax.Array  # [20] s' of the last step (== obs unless done)
    episode_return: jax.Array  # () f32, return of the ended episode (valid when done)
    episode_length: jax.Array  # () int32, length of the ended episode (valid when done)
    collision_speed: jax.Array  # () f32, mean speed of its last 3 steps (valid on collision)
    key: jax.Array  # PRNG key for the next spawn
    pose: jax.Array  # [3] x, y, θ
    goal: jax.Array  # [2]
    steps: jax.Array  # () int32, steps taken in the current episode
    running_return: jax.Array  # () f32, return so far of the current episode
    speeds: jax.Array  # [3] speed of the last three steps (m/s), newest last
    qvel: jax.Array  # [3] body velocity (ẋ, ẏ, θ̇) under motion "mjx"; [0] under "kinematic"
    invalid_action: jax.Array  # () bool, the last action was non-finite (treated as stop)
    spawn_valid: jax.Array  # () bool, the current episode's spawn met every rule
    layout: jax.Array  # [n, 5] boxes of a procedural arena; [0, 5] for fixed arenas
