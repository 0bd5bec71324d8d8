"""The car's 20-d observation from an RPLIDAR scan, a tracked pose and the goal (paper §5.2).

Layout, units and frames are those of ``spec.py``. Outline::

    scan  (quality, angle° CLOCKWISE, distance mm; 0 mm = invalid)   # RPLIDAR python packages
        θ_robot = radians(-angle) + mount_yaw;  r = mm / 1000
        P = zones.reduce_to_zones(θ_robot, r, valid, range_offset=...)   # same as the simulator
    pose  (x, y, θ, t) from the external tracker, world (arena) frame
        (v_x, v_y) = (p_t - p_prev) / (t - t_prev)      # world frame, finite difference
    goal  (g_x, g_y):  δ = wrap(atan2(g_y - y, g_x - x) - θ) ∈ [-π, π),  d = |g - p|
    obs = [P (16), δ, d, v_x, v_y]   float32

The finite difference uses the tracker's own timestamps ``t`` between the poses seen by two
consecutive builds, i.e. the displacement over about one control period like the simulator
(``spec.py``: v = displacement over the last period / dt; 0 at the first step). The same
pose seen twice (same ``t`` and position, a tracker slower than the loop) keeps the last
velocity instead of dividing by zero.

Every problem raises ``ObservationError`` with a reason code: ``scan_format``, ``scan_nan``,
``scan_empty`` (fewer valid readings than ``min_valid_points``: an empty zone reads max range,
i.e. "free", so a blind lidar must not pass), ``pose_nan``, ``pose_time`` (timestamp went
backwards, or two positions with one timestamp), ``pose_jump`` (speed above ``max_speed``:
a tracker glitch), ``stale_scan`` / ``stale_pose`` (``check_fresh``), ``goal_outside``.
After ``pose_jump`` / ``pose_time`` the new pose becomes the reference, so one glitch costs
at most two cycles and the builder recovers by itself.
"""

from __future__ import annotations

import dataclasses
import math
from typing import Any

import numpy as np

from advisor_jax.runner import spec, zones
from advisor_jax.runner.errors import ObservationError

# Bound once: the per-cycle code below calls them directly (bench_runner.py's budget).
_add_reduce, _min_reduce = np.add.reduce, np.minimum.reduce
_subtract, _multiply, _divide = np.subtract, np.multiply, np.divide
_minimum, _maximum, _radians, _floor = np.minimum, np.maximum, np.radians, np.floor
_bitwise_and, _less, _less_equal = np.bitwise_and, np.less, np.less_equal
_putmask, _count_nonzero = np.putmask, np.count_nonzero
# 0-d arrays: a ufunc takes them without converting a Python number on every call; same values
_ZONE_START, _ZONE_WIDTH = np.full((), zones.ZONE_START_RAD), np.full((), zones.ZONE_WIDTH_RAD)
_ZONE_MASK = np.full((), spec.N_ZONES - 1, dtype=np.int32)  # as zones.zone_index
_MM, _ZERO = np.full((), 1e-3), np.full((), 0.0)  # mm → m as scan_to_robot_frame; clip at 0


@dataclasses.dataclass(frozen=True)
class Scan:
    """One lidar turn. ``points`` [n, 3] float64: quality, angle (deg, clockwise), distance
    (mm, 0 = invalid), as yielded by ``rplidar.RPLidar.iter_scans``; ``stamp``: loop-clock
    time at which the turn was received (s)."""

    points: np.ndarray
    stamp: float


@dataclasses.dataclass(frozen=True)
class Pose:
    """Tracked pose in the world (arena) frame of ``spec.py``: x, y (m), theta (rad, CCW from
    +x); ``t``: the tracker's capture time (s, its own clock; used for velocity);
    ``stamp``: loop-clock time of reception (s; used for staleness)."""

    x: float
    y: float
    theta: float
    t: float
    stamp: float


@dataclasses.dataclass(frozen=True)
class ObservationConfig:
    """How raw car data become an observation. Defaults suit the paper's RC car."""

    max_range: float = spec.MAX_RANGE
    """Zone cutoff (m); from policy.json."""
    range_offset: float = 0.0
    """Subtracted from every lidar range (m): lidar origin to body edge; from policy.json."""
    mount_yaw_deg: float = 0.0
    """Robot-frame direction (deg, CCW) of the lidar's 0° mark; 180 for a lidar mounted
    back to front."""
    min_quality: float = 0.0
    """Readings with a lower RPLIDAR quality are dropped."""
    min_range: float = 0.0
    """m; closer readings are dropped (hits on the car's own chassis, or below the lidar's
    minimum range, 0.15 m for an A2). 0 keeps everything but the 0 mm "invalid" marks."""
    min_valid_points: int = 20
    """A scan with fewer valid readings is refused (scan_empty)."""
    max_speed: float = 3.0
    """m/s; a faster finite-difference speed is a tracker glitch (pose_jump)."""
    bounds: tuple[float, float, float, float] | None = None
    """Arena (xmin, xmax, ymin, ymax) from policy.json; the goal must lie inside."""

    def __post_init__(self):
        for name in ("max_range", "max_speed"):
            value = getattr(self, name)
            if not math.isfinite(value) or value <= 0:
                raise ValueError(f"ObservationConfig.{name}={value!r} must be positive")
        for name in ("range_offset", "mount_yaw_deg", "min_quality", "min_range"):
            if not math.isfinite(getattr(self, name)):
                raise ValueError(f"ObservationConfig.{name} must be finite")
        for name in ("range_offset", "min_range"):
            if getattr(self, name) < 0:
                raise ValueError(f"ObservationConfig.{name}={getattr(self, name)} must be >= 0")
        if int(self.min_valid_points) < 1:
            raise ValueError(f"min_valid_points={self.min_valid_points} must be >= 1")


def scan_points(raw: Any) -> np.ndarray:
    """RPLIDAR measurements (list of (quality, angle, distance) or array) → [n, 3] float64."""
    try:
        points = np.asarray(raw, dtype=np.float64)
    except (TypeError, ValueError) as e:
        msg = f"scan is not numeric (quality, angle, mm): {e}"
        raise ObservationError("scan_format", msg) from None
    if points.ndim != 2 or points.shape[1] != 3 or len(points) == 0:
        raise ObservationError(
            "scan_format",
            f"scan must be [n, 3] (quality, angle deg clockwise, distance mm), got shape "
            f"{list(points.shape)}",
        )
    return points


def scan_to_robot_frame(
    points: np.ndarray, mount_yaw_deg: float = 0.0
) -> tuple[np.ndarray, np.ndarray]:
    """[n, 3] RPLIDAR points → (robot-frame CCW angles [n] rad, ranges [n] m)."""
    angles = np.radians(mount_yaw_deg - points[:, 1])  # clockwise degrees → CCW radians
    return angles, points[:, 2] * 1e-3


def rplidar_zones(
    points: np.ndarray,
    dropped: np.ndarray,
    *,
    mount_yaw_deg: float = 0.0,
    max_range: float = spec.MAX_RANGE,
    range_offset: float = 0.0,
) -> np.ndarray:
    """[16] zone distances of a checked RPLIDAR scan: the car's per-cycle reduction.

    ``dropped`` [n] bool marks the readings to leave out. Equals
    ``zones.reduce_to_zones(*scan_to_robot_frame(points, mount_yaw_deg), ~dropped, ...)``
    bit for bit (tests/runner checks it) for a scan whose readings are finite, with every
    distance <= 0 dropped, which is what ``ObservationBuilder.zones`` has checked by then.
    It is written for the control cycle's latency budget (``bench_runner.py``), where
    numpy's per-call overhead dominates, so it makes as few and as cheap calls as it can:

    * the zone of each reading is ``zones.zone_index(radians(mount_yaw - angle))``, the same
      floating-point operations in the same order, done in place in one buffer; dropped
      readings go to a 17th, discarded zone;
    * the minimum is taken over the raw millimetres and only the 16 minima are converted to
      free distance. The conversion ``f(mm) = min(max(mm * 1e-3 - offset, 0), max_range)`` is
      non-decreasing in floating point too (every step is a correctly rounded monotone
      operation), so ``f(min mm) == min f(mm)`` exactly; an empty zone is ``f(inf) ==
      max_range``, as in the generic path.
    """
    k = _subtract(mount_yaw_deg, points[:, 1])  # as scan_to_robot_frame, then zone_index
    _radians(k, out=k)
    _subtract(_ZONE_START, k, out=k)
    _divide(k, _ZONE_WIDTH, out=k)
    _floor(k, out=k)
    index = k.astype(np.int32)
    _bitwise_and(index, _ZONE_MASK, out=index)
    _putmask(index, dropped, spec.N_ZONES)
    mm = np.full(spec.N_ZONES + 1, np.inf)
    _minimum.at(mm, index, points[:, 2])
    mm = mm[: spec.N_ZONES]
    _multiply(mm, _MM, out=mm)  # f(mm) on the 16 minima
    _subtract(mm, range_offset, out=mm)
    _maximum(mm, _ZERO, out=mm)
    _minimum(mm, max_range, out=mm)
    return mm


def goal_features(x: float, y: float, theta: float, gx: float, gy: float) -> tuple[float, float]:
    """(δ, d): goal angle from the heading, CCW, wrapped to [-π, π), and distance."""
    dx, dy = gx - x, gy - y
    return spec.wrap_angle(math.atan2(dy, dx) - theta), math.hypot(dx, dy)


def check_fresh(what: str, stamp: float, now: float, max_age: float) -> None:
    """Raises ``stale_<what>`` when data are older than ``max_age`` seconds at ``now``."""
    age = now - stamp
    if not age <= max_age:  # also catches NaN stamps
        raise ObservationError(
            f"stale_{what}", f"{what} is {age * 1e3:.0f} ms old (limit {max_age * 1e3:.0f} ms)"
        )


def check_goal(goal: tuple[float, float], bounds: tuple[float, ...] | None) -> None:
    """Raises ``goal_outside`` for a non-finite goal or one outside the arena bounds."""
    gx, gy = (float(v) for v in goal)
    if not (math.isfinite(gx) and math.isfinite(gy)):
        raise ObservationError("goal_outside", f"goal ({gx}, {gy}) is not finite")
    if bounds is not None:
        xmin, xmax, ymin, ymax = bounds
        if not (xmin <= gx <= xmax and ymin <= gy <= ymax):
            raise ObservationError(
                "goal_outside",
                f"goal ({gx:g}, {gy:g}) is outside the arena bounds x in [{xmin:g}, {xmax:g}], "
                f"y in [{ymin:g}, {ymax:g}] of policy.json",
            )


class ObservationBuilder:
    """Stateful (last pose, last velocity) builder of observations for one goal."""

    def __init__(self, config: ObservationConfig, goal: tuple[float, float]):
        check_goal(goal, config.bounds)
        self.config = config
        self.goal = (float(goal[0]), float(goal[1]))
        # The per-cycle constants as 0-d float64 arrays (cheaper ufunc arguments, same values)
        self._yaw, self._max_range, self._offset, self._min_mm = (
            np.full((), float(v))
            for v in (config.mount_yaw_deg, config.max_range, config.range_offset,
                      config.min_range * 1e3)
        )  # fmt: skip
        self.reset()

    def reset(self) -> None:
        """Forget the previous pose: the next velocity is 0 (like an episode start)."""
        self._prev: tuple[float, float, float] | None = None  # (x, y, t)
        self._vel = (0.0, 0.0)

    def zones(self, scan: Scan) -> np.ndarray:
        """[16] float32 proximity zones of a scan; raises ObservationError if unusable."""
        return self._zones(scan).astype(np.float32)

    def _zones(self, scan: Scan) -> np.ndarray:
        """``zones`` in float64, before the observation's cast to float32."""
        cfg, points = self.config, scan.points
        if not (type(points) is np.ndarray and points.dtype == np.float64):
            points = scan_points(points)  # lists of tuples, ints, objects: convert or refuse
        if points.ndim != 2 or points.shape[1] != 3:
            points = scan_points(points)  # raises scan_format
        if not math.isfinite(_add_reduce(points, None)):  # one reduction: NaN and inf propagate
            if np.isfinite(points).all():
                raise ObservationError("scan_format", "scan values overflow (not mm, degrees)")
            raise ObservationError("scan_nan", "scan contains NaN or inf values")
        dist = points[:, 2]
        if len(dist) and _min_reduce(dist) < 0:
            raise ObservationError("scan_format", "scan has negative distances")
        dropped = _less_equal(dist, self._min_mm)  # always drops the 0 mm "invalid" marks
        if cfg.min_quality > 0:
            dropped |= _less(points[:, 0], cfg.min_quality)
        n_valid = len(dist) - _count_nonzero(dropped)
        if n_valid < cfg.min_valid_points:
            raise ObservationError(
                "scan_empty",
                f"scan has {n_valid} valid readings of {len(points)} (need {cfg.min_valid_points})",
            )
        return rplidar_zones(
            points,
            dropped,
            mount_yaw_deg=self._yaw,
            max_range=self._max_range,
            range_offset=self._offset,
        )

    def velocity(self, pose: Pose) -> tuple[float, float]:
        """World-frame (v_x, v_y) by finite difference; updates the reference pose."""
        x, y, t = pose.x, pose.y, pose.t
        prev = self._prev
        if prev is None:
            self._prev, self._vel = (x, y, t), (0.0, 0.0)
        elif t == prev[2]:
            if (x, y) != prev[:2]:
                self._prev, self._vel = (x, y, t), (0.0, 0.0)
                raise ObservationError("pose_time", f"two different poses with timestamp {t}")
        elif t < prev[2]:
            self._prev, self._vel = (x, y, t), (0.0, 0.0)
            raise ObservationError(
                "pose_time", f"pose timestamp went backwards ({prev[2]:.3f} → {t:.3f} s)"
            )
        else:
            dt = t - prev[2]
            vx, vy = (x - prev[0]) / dt, (y - prev[1]) / dt
            self._prev = (x, y, t)
            speed = math.hypot(vx, vy)
            if speed > self.config.max_speed:
                self._vel = (0.0, 0.0)
                raise ObservationError(
                    "pose_jump",
                    f"pose moved {speed * dt:.2f} m in {dt * 1e3:.0f} ms ({speed:.1f} m/s > "
                    f"limit {self.config.max_speed:g} m/s)",
                )
            self._vel = (vx, vy)
        return self._vel

    def build(self, scan: Scan, pose: Pose) -> np.ndarray:
        """[20] float32 observation (``spec.py`` layout)."""
        obs = np.empty(spec.OBS_SIZE, dtype=np.float32)
        obs[spec.OBS_PROXIMITY] = self._zones(scan)  # the cast of ``zones``
        x, y, theta, t = pose.x, pose.y, pose.theta, pose.t
        values = (x, y, theta, t)
        if not math.isfinite(x + y + theta + t) and not all(map(math.isfinite, values)):
            raise ObservationError("pose_nan", f"pose (x, y, theta, t) = {values} is not finite")
        obs[18], obs[19] = self.velocity(pose)
        obs[spec.OBS_GOAL_ANGLE], obs[spec.OBS_GOAL_DISTANCE] = goal_features(
            x, y, theta, *self.goal
        )
        return obs
