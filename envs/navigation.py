"""The navigation environment: reset/step of one robot in one arena, jit- and vmap-safe.

Paper §5.1–5.4, Eq. (8), Table A3; DESIGN.md "Environment". Per control step (dt)::

    a      ← clip(action) (non-finite → stop, flagged)      V = a0·V_max, ω = a1·ω_max
    pose   ← unicycle move over dt (heading at mid-step: exact speed, 2nd-order arc)
    P      ← MJX rangefinders at the new pose (mjx.kinematics + mjx.sensor_pos), −1 → max_range;
             physical arena: 200-beam lidar → 16 zones (runner.zones.reduce_to_zones)
    obs    = [P, δ, d, v_x, v_y]                            (layout: advisor_jax/runner/spec.py)
    goal   = d_t ≤ T_g;  collision = min P ≤ T_c  or  robot circle touches a box (geometry)
    r      = c1 if goal, else −c2 if collision, else k1 (d_{t−1} − d_t) + k2 (p_t − p_{t−1})
    timeout after h_max steps without goal/collision (no special reward; a truncation)
    if done: draw a fresh start, goal (and procedural layout); obs = its first observation

The robot is kinematic: the pose is integrated here and written to ``qpos``; MJX then
computes the sensors (``mjcf.MjxSensors``), so the readings are MuJoCo's. The state keeps
only the pose, not ``mjx.Data``, which is rebuilt from a constant template each step.
Fixed arenas keep one unbatched ``mjx.Model`` (closure constants); ``procedural`` carries
its boxes in the state and writes them into ``geom_pos/size/quat`` of a per-env model
(domain randomisation). Measured on an H100 (``results/bench_env.md``), this is faster than
setting ``qvel`` and calling ``mjx.step``, whose sensors would also describe the pose
before the move. Because vmap turns the auto-reset branch into a select, every step also
samples a spawn and reads its sensors; both sensor passes share one vmapped MJX call.

Episode spawns (``geometry``): start and goal uniform over the floor, heading uniform; the
robot footprint is ≥ ``start_clearance`` (0.2 m) from every box at the start, so p_0 ≥ 0.2 m
> T_c; the goal point is ≥ r + ``goal_clearance`` (0.1 m) from every box, so the footprint
fits there; |goal − start| ≥ ``min_goal_distance`` (1 m). Fixed arenas sample from
precomputed free-cell tables (exact, one start candidate, goal candidates only rejected for
the distance); the procedural arena rejection-samples 64 candidates. If no candidate
qualifies, the best one is used and ``NavState.spawn_valid`` is False. That happens with
probability below 1e-15 per spawn in the fixed arenas (by construction of the goal
candidate count) and about 1e-12 in the procedural arena (start acceptance 53 % in the
median layout, 28 % in the worst of 4000 layouts: 0.72^64 = 1e-9); the tests check that
thousands of resets never need it.
"""

from __future__ import annotations

import dataclasses
import math

import jax
import jax.numpy as jnp
import numpy as np
from flax import struct

from advisor_jax.advisor import AdvisorParams
from advisor_jax.runner import spec
from envs import geometry, layouts, mjcf
from envs.layouts import ARENA_SPECS

# Outcome codes of an episode (NavState.outcome).
RUNNING, GOAL, COLLISION, TIMEOUT = 0, 1, 2, 3
OUTCOME_NAMES = ("running", "goal", "collision", "timeout")
OMEGA_MAX = 3.0  # rad/s; the paper leaves ω_max open (calibration, results/advisor.md)
SPEED_HISTORY = 3  # steps averaged for the collision speed
SPAWN_CELL = 0.02  # m, grid of the fixed arenas' free-cell spawn tables


@dataclasses.dataclass(frozen=True)
class EnvConfig:
    """Static environment settings; defaults are the paper's (Tables A1-A3) or documented."""

    dt: float = spec.CONTROL_DT  # s, control period (V-REP's default step)
    v_max: float = spec.V_MAX  # m/s, V = a0 · v_max
    omega_max: float = OMEGA_MAX  # rad/s, ω = a1 · omega_max (not in the paper; calibrated)
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

    def __post_init__(self):
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
    collision_speed: jax.Array  # () f32, mean |V| of its last 3 steps (valid on collision)
    key: jax.Array  # PRNG key for the next spawn
    pose: jax.Array  # [3] x, y, θ
    goal: jax.Array  # [2]
    steps: jax.Array  # () int32, steps taken in the current episode
    running_return: jax.Array  # () f32, return so far of the current episode
    speeds: jax.Array  # [3] |V| of the last three steps, newest last
    invalid_action: jax.Array  # () bool, the last action was non-finite (treated as stop)
    spawn_valid: jax.Array  # () bool, the current episode's spawn met every rule
    layout: jax.Array  # [n, 5] boxes of a procedural arena; [0, 5] for fixed arenas


class NavEnv:
    """One arena. ``reset``/``step`` are pure functions of explicit state."""

    def __init__(self, arena: str, config: EnvConfig | None = None):
        if arena not in ARENA_SPECS:
            raise ValueError(f"unknown arena {arena!r}; choose one of {', '.join(ARENA_SPECS)}")
        self.arena_name = arena
        self.config = config if config is not None else EnvConfig()
        self._arena = ARENA_SPECS[arena]
        self.procedural = arena == "procedural"
        cfg = self.config
        self.max_episode_steps = cfg.max_episode_steps or self._arena.h_max
        if self._arena.sensor == "lidar":
            self.rig = mjcf.lidar_rig(cfg.lidar_beams, cfg.robot_radius, cfg.max_range)
        else:
            self.rig = mjcf.sonar_rig(cfg.robot_radius, cfg.max_range)
        if self.procedural:
            self.bounds = layouts.ARENA_5M
            self._boxes = np.asarray(layouts.procedural_boxes(jax.random.PRNGKey(0)))
        else:
            lay = layouts.FIXED_LAYOUTS[arena]
            self.bounds, self._boxes = lay.bounds, lay.boxes
        self.sensors = mjcf.MjxSensors(
            self.xml(self._boxes),
            self.rig,
            len(self._boxes),
            per_env_boxes=self.procedural,
            max_range=cfg.max_range,
            robot_radius=cfg.robot_radius,
        )
        self.mj_model = self.sensors.mj_model  # CPU MuJoCo model (tests, viewers)
        if not self.procedural:
            try:
                self.spawn_tables = geometry.make_spawn_tables(
                    self._boxes,
                    self.bounds,
                    radius=cfg.robot_radius,
                    start_clearance=cfg.start_clearance,
                    goal_clearance=cfg.goal_clearance,
                    min_goal_distance=cfg.min_goal_distance,
                    max_goal_candidates=cfg.spawn_candidates,
                    cell=SPAWN_CELL,
                )
            except ValueError as err:
                raise ValueError(f"arena {arena!r}: {err}") from None
        self._jit_step = jax.jit(self._step)
        self._jit_reset = jax.jit(self._reset)

    # ---- static description -----------------------------------------------------------
    observation_size = spec.OBS_SIZE
    action_size = spec.ACTION_SIZE

    @property
    def advisor_params(self) -> AdvisorParams:
        """Table A1 advisor with this arena's obstacle threshold T_o."""
        return AdvisorParams(obstacle_threshold=self._arena.obstacle_threshold)

    def xml(self, boxes: np.ndarray | None = None) -> str:
        """Standalone MJCF of this arena (procedural: of the given box array)."""
        boxes = self._boxes if boxes is None else np.asarray(boxes)
        cfg = self.config
        return mjcf.arena_xml(
            self.arena_name, boxes, self.bounds, self.rig, robot_radius=cfg.robot_radius, dt=cfg.dt
        )

    def layout_boxes(self, key: jax.Array | None = None) -> np.ndarray:
        """[n, 5] boxes: the fixed layout, or (procedural) the layout of the first episode
        of ``reset(key)``."""
        if self.procedural and key is not None:
            return np.asarray(layouts.procedural_boxes(jax.random.split(key, 3)[1]))
        return np.array(self._boxes)

    def metadata(self) -> dict:
        """JSON-able description of the simulated robot and sensors (for the exporter)."""
        cfg = self.config
        meta = {
            "arena": self.arena_name,
            "dt": cfg.dt,
            "v_max": cfg.v_max,
            "omega_max": cfg.omega_max,
            "max_range": cfg.max_range,
            "robot_radius": cfg.robot_radius,
            "sensor": self.rig.kind,
            "h_max": self.max_episode_steps,
            "T_g": cfg.goal_tolerance,
            "T_c": cfg.collision_distance,
            "T_o": self._arena.obstacle_threshold,
            "bounds": list(self.bounds),
            "observation_names": list(spec.OBS_NAMES),
            "observation_units": list(spec.OBS_UNITS),
        }
        if self.rig.kind == "lidar":
            meta |= {
                "lidar_beams_deg": list(self.rig.directions_deg),
                "lidar_range_offset": cfg.robot_radius,
                "lidar_cutoff": self.rig.cutoff,
                "zone_start_deg": spec.ZONE_START_DEG,
                "zone_width_deg": spec.ZONE_WIDTH_DEG,
            }
        else:
            meta |= {
                "sonar_directions_deg": list(spec.SONAR_DIRECTIONS_DEG),
                "sonar_mounts_deg": list(spec.SONAR_MOUNTS_DEG),
                "lidar_range_offset": 0.0,
            }
        return meta

    # ---- sensing (MJX, envs/mjcf.py) ----------------------------------------------------
    def sensor_readings(self, pose: jax.Array, layout: jax.Array | None = None) -> jax.Array:
        """Raw MJX rangefinder readings [n_rays] at ``pose`` (−1 = no hit within cutoff);
        ``layout``: the procedural arena's boxes (ignored by fixed arenas)."""
        return self.sensors.readings(pose, layout if self.procedural else None)

    def proximity(self, pose: jax.Array, layout: jax.Array | None = None) -> jax.Array:
        """The 16 proximity readings P (m) of the observation at ``pose``."""
        return self.sensors.proximity(pose, layout if self.procedural else None)

    def _boxes_of(self, layout: jax.Array | None) -> jax.Array:
        if self.procedural:
            return jnp.asarray(self._boxes if layout is None else layout)
        return jnp.asarray(self._boxes)

    def observe(self, pose, goal, prox, velocity) -> jax.Array:
        """[20] observation from pose [3], goal [2], proximity [16], velocity [2]."""
        to_goal = goal - pose[:2]
        dist = jnp.linalg.norm(to_goal)
        bearing = jnp.arctan2(to_goal[1], to_goal[0]) - pose[2]
        delta = jnp.mod(bearing + jnp.pi, 2.0 * jnp.pi) - jnp.pi
        return jnp.concatenate([prox, jnp.stack([delta, dist]), velocity]).astype(jnp.float32)

    # ---- reset / step -----------------------------------------------------------------
    def reset(self, key: jax.Array) -> NavState:
        """Fresh episode: random layout (procedural), start pose and goal.

        Always goes through ``jax.jit`` (inlined when traced inside another jit), so that
        ``jax.vmap(env.reset)(keys)`` compiles instead of running op by op."""
        return self._jit_reset(key)

    def step(self, state: NavState, action: jax.Array) -> NavState:
        """One control step with auto-reset. ``action`` [2] normalised (V, ω).

        Called on concrete values it first checks the action (ValueError on a wrong shape or
        a non-finite value); traced (jit/vmap/scan), a non-finite action is a stop command
        and sets ``invalid_action``."""
        if isinstance(action, jax.core.Tracer) or isinstance(state.pose, jax.core.Tracer):
            return self._jit_step(state, action)
        bad = np.asarray(action)
        if bad.shape != (spec.ACTION_SIZE,):
            raise ValueError(f"action must have shape [2] (V, ω) for one env, got {bad.shape}")
        if not np.all(np.isfinite(bad)):
            raise ValueError(f"non-finite action {bad.tolist()}: V and ω must be finite numbers")
        return self._jit_step(state, action)

    def _spawn(self, key: jax.Array) -> tuple[jax.Array, jax.Array, geometry.Spawn]:
        """(next key, layout, spawn) of a new episode; its sensors are not read here."""
        if not self.procedural:
            key_next, key_spawn = jax.random.split(key)
            return key_next, jnp.zeros((0, 5), jnp.float32), self.spawn_tables.sample(key_spawn)
        cfg = self.config
        key_next, key_layout, key_spawn = jax.random.split(key, 3)
        layout = layouts.procedural_boxes(key_layout)
        spawn = geometry.sample_spawn(
            key_spawn,
            layout,
            self.bounds,
            radius=cfg.robot_radius,
            start_clearance=cfg.start_clearance,
            goal_clearance=cfg.goal_clearance,
            min_goal_distance=cfg.min_goal_distance,
            n_candidates=cfg.spawn_candidates,
        )
        return key_next, layout, spawn

    def _reset(self, key: jax.Array) -> NavState:
        key_next, layout, spawn = self._spawn(key)
        return self._first_state(key_next, layout, spawn, self.proximity(spawn.pose, layout))

    def _first_state(self, key_next, layout, spawn: geometry.Spawn, prox) -> NavState:
        obs = self.observe(spawn.pose, spawn.goal, prox, jnp.zeros(2, jnp.float32))
        zero_f, zero_i = jnp.float32(0.0), jnp.int32(0)
        return NavState(
            obs=obs,
            reward=zero_f,
            done=jnp.bool_(False),
            terminal=jnp.bool_(False),
            outcome=zero_i,
            terminal_obs=obs,
            episode_return=zero_f,
            episode_length=zero_i,
            collision_speed=zero_f,
            key=key_next,
            pose=spawn.pose.astype(jnp.float32),
            goal=spawn.goal.astype(jnp.float32),
            steps=zero_i,
            running_return=zero_f,
            speeds=jnp.zeros(SPEED_HISTORY, jnp.float32),
            invalid_action=jnp.bool_(False),
            spawn_valid=spawn.valid,
            layout=layout,
        )

    def _step(self, state: NavState, action: jax.Array) -> NavState:
        cfg = self.config
        action = jnp.asarray(action, jnp.float32)
        finite = jnp.all(jnp.isfinite(action))
        action = jnp.where(finite, action, 0.0)
        v = jnp.clip(action[0], spec.ACTION_LOW[0], spec.ACTION_HIGH[0]) * cfg.v_max
        w = jnp.clip(action[1], spec.ACTION_LOW[1], spec.ACTION_HIGH[1]) * cfg.omega_max

        x, y, theta = state.pose[0], state.pose[1], state.pose[2]
        mid = theta + 0.5 * w * cfg.dt
        step_xy = v * cfg.dt * jnp.stack([jnp.cos(mid), jnp.sin(mid)])
        heading = jnp.mod(theta + w * cfg.dt + jnp.pi, 2.0 * jnp.pi) - jnp.pi
        pose = jnp.concatenate([jnp.stack([x, y]) + step_xy, heading[None]])
        velocity = step_xy / cfg.dt

        # The auto-reset branch is computed every step (vmap turns a branch into a select),
        # so the fresh start's sensors are read in the same MJX call as the moved pose's.
        key_next, fresh_layout, spawn = self._spawn(state.key)
        both = jax.vmap(self.proximity)(
            jnp.stack([pose, spawn.pose]), jnp.stack([state.layout, fresh_layout])
        )  # [2, 16]
        prox = both[0]
        fresh = self._first_state(key_next, fresh_layout, spawn, both[1])
        obs = self.observe(pose, state.goal, prox, velocity)
        dist, p_min = obs[spec.OBS_GOAL_DISTANCE], jnp.min(prox)
        dist_prev = state.obs[spec.OBS_GOAL_DISTANCE]
        p_prev = jnp.min(state.obs[spec.OBS_PROXIMITY])

        goal = dist <= cfg.goal_tolerance
        collision = p_min <= cfg.collision_distance
        if cfg.footprint_collision:
            boxes = self._boxes_of(state.layout)
            collision |= geometry.footprint_collides(pose[:2], cfg.robot_radius, boxes)
        collision &= ~goal  # the goal wins when both happen in one step
        shaped = cfg.k_distance * (dist_prev - dist) + cfg.k_proximity * (p_min - p_prev)
        reward = jnp.where(
            goal, cfg.goal_reward, jnp.where(collision, -cfg.collision_penalty, shaped)
        )

        steps = state.steps + 1
        timeout = (steps >= self.max_episode_steps) & ~goal & ~collision
        done = goal | collision | timeout
        outcome = jnp.select([goal, collision, timeout], [GOAL, COLLISION, TIMEOUT], RUNNING)
        speeds = jnp.concatenate([state.speeds[1:], jnp.abs(v)[None]])
        recent = jnp.minimum(steps, SPEED_HISTORY)
        collision_speed = jnp.sum(speeds) / recent.astype(jnp.float32)
        episode_return = state.running_return + reward

        keep = lambda new, old: jnp.where(done, new, old)  # noqa: E731
        return NavState(
            obs=keep(fresh.obs, obs),
            reward=reward.astype(jnp.float32),
            done=done,
            terminal=goal | collision,
            outcome=outcome.astype(jnp.int32),
            terminal_obs=obs,
            episode_return=episode_return.astype(jnp.float32),
            episode_length=steps,
            collision_speed=collision_speed,
            key=keep(fresh.key, state.key),
            pose=keep(fresh.pose, pose),
            goal=keep(fresh.goal, state.goal),
            steps=keep(0, steps).astype(jnp.int32),
            running_return=keep(0.0, episode_return).astype(jnp.float32),
            speeds=keep(fresh.speeds, speeds),
            invalid_action=~finite,
            spawn_valid=keep(fresh.spawn_valid, state.spawn_valid),
            layout=keep(fresh.layout, state.layout),
        )
