"""The navigation environment: reset/step of one robot in one arena, jit- and vmap-safe.

Paper §5.1–5.4, Eq. (8), Table A3; docs/architecture.md, "Environment". Per control step (dt)::

    a      ← clip(action) (non-finite → stop, flagged)      V = a0·V_max, ω = a1·ω_max
    pose   ← move over dt by the motion model (``motion.py``): "kinematic" unicycle, or
             "mjx": the P3DX's wheels and body stepped by mjx.step (state keeps qvel)
    P      ← MJX rangefinders at the new pose (mjx.kinematics + mjx.sensor_pos), −1 → max_range;
             physical arena: 200-beam lidar → 16 zones (contract.zones.reduce_to_zones)
    obs    = [P, δ, d, v_x, v_y]   v = displacement / dt   (layout: advisor_jax/contract/spec.py)
    goal   = d_t ≤ T_g;  collision = min P ≤ T_c  or  robot circle touches a box (geometry)
    r      = c1 if goal, else −c2 if collision, else k1 (d_{t−1} − d_t) + k2 (p_t − p_{t−1})
    timeout after h_max steps without goal/collision (no special reward; a truncation)
    if done: draw a fresh start, goal (and procedural layout); obs = its first observation

The motion model moves the pose (and, under "mjx", the body velocity ``qvel``); the pose
is then written to ``qpos`` and MJX computes the sensors (``mjcf.MjxSensors``), so the
readings are MuJoCo's at the pose after the move. The state keeps only the pose (and
qvel), not ``mjx.Data``, which is rebuilt from a constant template each step.
Fixed arenas keep one unbatched ``mjx.Model`` (closure constants); ``procedural`` carries
its boxes in the state and writes them into ``geom_pos/size/quat`` of a per-env model
(domain randomisation). Reading the sensors this way is faster than inside
``mjx.step`` (``results/bench_env.md``), whose sensors would describe the pose before the
move; the "mjx" motion model therefore steps a robot-only model with sensors off.
Because vmap turns the auto-reset branch into a select, every step also samples a spawn
and reads its sensors; both sensor passes share one vmapped MJX call.

Episode spawns (``geometry``): start and goal uniform over the floor, heading uniform; the
robot footprint is ≥ ``start_clearance`` (0.2 m) from every box at the start, so p_0 ≥ 0.2 m
> T_c; the goal point is ≥ r + ``goal_clearance`` (0.1 m) from every box, so the footprint
fits there; |goal − start| ≥ ``min_goal_distance`` (1 m). Fixed arenas sample from
precomputed free-cell tables (exact, one start candidate, goal candidates only rejected for
the distance); the procedural arena rejection-samples 64 candidates. If no candidate
qualifies, the best one is used and ``NavState.spawn_valid`` is False; the fixed arenas'
goal candidate count makes that vanishingly rare by construction, and the tests check
that thousands of resets in every arena never need it.
"""

from __future__ import annotations

import jax
import jax.numpy as jnp
import numpy as np

from advisor_jax.contract import spec
from envs import geometry, layouts, mjcf, motion
from envs.layouts import ARENA_SPECS
from envs.state import (
    COLLISION,
    GOAL,
    OMEGA_MAX,
    OUTCOME_NAMES,
    RUNNING,
    SPAWN_CELL,
    SPEED_HISTORY,
    TIMEOUT,
    EnvConfig,
    NavState,
)

__all__ = [
    "COLLISION", "GOAL", "OMEGA_MAX", "OUTCOME_NAMES", "RUNNING", "TIMEOUT",
    "EnvConfig", "NavEnv", "NavState",
]  # fmt: skip


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
        self.drive = None  # the "mjx" motion model's stepper (motion.MjxDrive)
        if cfg.motion == "mjx":
            xml = mjcf.drive_xml(cfg.drive, cfg.dt, cfg.robot_radius)
            self.drive = motion.MjxDrive(xml, cfg.drive, cfg.dt)
        if not self.procedural:
            try:
                self.spawn_tables = geometry.make_spawn_tables(
                    self._boxes,
                    self.bounds,
                    **self._spawn_rules(),
                    max_goal_candidates=cfg.spawn_candidates,
                    cell=SPAWN_CELL,
                )
            except ValueError as err:
                raise ValueError(f"arena {arena!r}: {err}") from None

    # ---- static description -----------------------------------------------------------
    observation_size = spec.OBS_SIZE
    action_size = spec.ACTION_SIZE

    @property
    def obstacle_threshold(self) -> float:
        """T_o of this arena (m): the advisor's switch to obstacle avoidance (Table A1)."""
        return self._arena.obstacle_threshold

    def xml(self, boxes: np.ndarray | None = None) -> str:
        """Standalone MJCF of this arena (procedural: of the given box array)."""
        boxes = self._boxes if boxes is None else np.asarray(boxes)
        cfg = self.config
        return mjcf.arena_xml(
            self.arena_name,
            boxes,
            self.bounds,
            self.rig,
            robot_radius=cfg.robot_radius,
            dt=cfg.dt,
            drive=cfg.drive if cfg.motion == "mjx" else None,
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
            "motion": cfg.motion_setting,
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

        A pure function: jit it at the call site (``jax.jit(jax.vmap(env.reset))``)."""
        key_next, layout, spawn = self._spawn(key)
        return self._first_state(key_next, layout, spawn, self.proximity(spawn.pose, layout))

    def step(self, state: NavState, action: jax.Array) -> NavState:
        """One control step with auto-reset. ``action`` [2] normalised (V, ω).

        A pure function: jit it at the call site. Called on a concrete action it first
        checks it (ValueError on a wrong shape or a non-finite value); traced (jit, vmap,
        scan), a non-finite action is a stop command and sets ``invalid_action``."""
        if not isinstance(action, jax.core.Tracer):
            bad = np.asarray(action)
            if bad.shape != (spec.ACTION_SIZE,):
                raise ValueError(f"action must have shape [2] (V, ω) for one env, got {bad.shape}")
            if not np.all(np.isfinite(bad)):
                raise ValueError(f"non-finite action {bad.tolist()}: V and ω must be finite")
        return self._step(state, action)

    def _spawn_rules(self) -> dict:
        """The clearances every spawn obeys (``geometry``), from the config."""
        cfg = self.config
        return dict(
            radius=cfg.robot_radius,
            start_clearance=cfg.start_clearance,
            goal_clearance=cfg.goal_clearance,
            min_goal_distance=cfg.min_goal_distance,
        )

    def _spawn(self, key: jax.Array) -> tuple[jax.Array, jax.Array, geometry.Spawn]:
        """(next key, layout, spawn) of a new episode; its sensors are not read here."""
        if not self.procedural:
            key_next, key_spawn = jax.random.split(key)
            return key_next, jnp.zeros((0, 5), jnp.float32), self.spawn_tables.sample(key_spawn)
        cfg = self.config
        key_next, key_layout, key_spawn = jax.random.split(key, 3)
        layout = layouts.procedural_boxes(key_layout)
        spawn = geometry.sample_spawn(
            key_spawn, layout, self.bounds, **self._spawn_rules(), n_candidates=cfg.spawn_candidates
        )
        return key_next, layout, spawn

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
            qvel=jnp.zeros(0 if self.drive is None else 3, jnp.float32),  # at rest
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

        if self.drive is None:  # kinematic: the commanded speed is the speed
            pose, velocity = motion.unicycle_move(state.pose, v, w, cfg.dt)
            qvel, speed = state.qvel, jnp.abs(v)
        else:  # mjx: the body's own motion over the step
            pose, velocity, qvel = self.drive.move(state.pose, state.qvel, v, w)
            speed = jnp.linalg.norm(velocity)

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
        speeds = jnp.concatenate([state.speeds[1:], speed[None]])
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
            qvel=keep(fresh.qvel, qvel),
            invalid_action=~finite,
            spawn_valid=keep(fresh.spawn_valid, state.spawn_valid),
            layout=keep(fresh.layout, state.layout),
        )
