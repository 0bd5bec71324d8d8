"""The car's 20-d observation from an RPLIDAR scan, a tracked pose and the goal (paper §5.2).

Layout, units and frames are those of ``spec.py``. Outline::

    scan  (quality, angle° CLOCKWISE, distance mm; 0 mm = invalid)   # RPLIDAR python packages
        zone of a reading: robot-frame angle mount_yaw - angle by spec.py's rule (zone_table)
        P = per-zone min of clip(mm / 1000 - range_offset, 0, max_range); empty zone: max_range
    pose  (x, y, θ, t) from the external tracker, world (arena) frame
        (v_x, v_y) = (p_t - p_prev) / (t - t_prev)      # world frame, finite difference
    goal  (g_x, g_y):  δ = wrap(atan2(g_y - y, g_x - x) - θ) ∈ [-π, π),  d = |g - p|
    obs = [P (16), δ, d, v_x, v_y]   float32

The finite difference uses the tracker's own timestamps ``t`` between the poses seen by two
consecutive builds, i.e. the displacement over about one control period like the simulator
(``spec.py``: v = displacement over the last period / dt; 0 at the first step). The same
pose seen twice (same ``t`` and position, a tracker slower than the loop) keeps the last
velocity instead of dividing by zero.

The zones are the simulator's rule (``contract/zones.py``, which the ``physical`` arena runs
on its beams), computed by ``runner/lidar_zones.py`` within the car's time budget;
tests/contract/test_zones.py proves the two equal on every reading the RPLIDAR can give
(every angle of its 1/64° grid, zone boundaries included).

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

from advisor_jax.contract import spec
from advisor_jax.runner.errors import ObservationError
from advisor_jax.runner.lidar_zones import (
    free_distances,
    mount_yaw_ticks,
    zone_minima_mm,
    zone_table,
)

_SCAN_NORM_LIMIT = 1e12
"""A scan whose values have a larger Euclidean norm is refused (scan_format): they are not
degrees and mm (a turn's norm is ~10^5), and angles stay far from int64 1/64° ticks' limit."""


# Bound once: the per-cycle code below calls them directly (bench_runner.py's budget).
_vdot, _less, _less_equal, _count_nonzero = np.vdot, np.less, np.less_equal, np.count_nonzero


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
    back to front. A multiple of 1/64° (the RPLIDAR's angle step; ``zone_table``)."""
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
        mount_yaw_ticks(self.mount_yaw_deg)  # zone_table's exactness needs the 1/64° grid
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
        self._table = zone_table(config.mount_yaw_deg)  # raises on an off-grid yaw
        self._min_mm = np.full((), config.min_range * 1e3)  # 0-d: cheaper ufunc argument
        self.reset()

    def reset(self) -> None:
        """Forget the previous pose: the next velocity is 0 (like an episode start)."""
        self._prev: tuple[float, float, float] | None = None  # (x, y, t)
        self._vel = (0.0, 0.0)

    def zones(self, scan: Scan) -> np.ndarray:
        """[16] float32 proximity zones of a scan; raises ObservationError if unusable."""
        return np.array(self._zones(scan), dtype=np.float32)

    def _zones(self, scan: Scan) -> list[float]:
        """``zones`` as 16 Python floats (float64), before the observation's cast to float32."""
        cfg, points = self.config, scan.points
        if not (type(points) is np.ndarray and points.dtype == np.float64):
            points = scan_points(points)  # lists of tuples, ints, objects: convert or refuse
        if points.ndim != 2 or points.shape[1] != 3:
            points = scan_points(points)  # raises scan_format
        # One sum of squares finds NaN, inf and absurd values alike (no term can cancel).
        if not _vdot(points, points) <= _SCAN_NORM_LIMIT**2:
            if not np.isfinite(points).all():
                raise ObservationError("scan_nan", "scan contains NaN or inf values")
            raise ObservationError(
                "scan_format", "scan values are implausibly large (not degrees and mm)"
            )
        dist = points[:, 2]
        dropped = _less_equal(dist, self._min_mm)  # always drops 0 mm ("invalid") and below
        if cfg.min_quality > 0:
            dropped |= _less(points[:, 0], cfg.min_quality)
        minima = zone_minima_mm(points, dropped, self._table)
        if minima[spec.N_ZONES] < 0:  # the dropped readings' slot
            raise ObservationError("scan_format", "scan has negative distances")
        n_valid = len(dist) - _count_nonzero(dropped)
        if n_valid < cfg.min_valid_points:
            raise ObservationError(
                "scan_empty",
                f"scan has {n_valid} valid readings of {len(points)} (need {cfg.min_valid_points})",
            )
        return free_distances(minima, cfg.max_range, cfg.range_offset)

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
        values = self._zones(scan)
        x, y, theta, t = pose.x, pose.y, pose.theta, pose.t
        if not math.isfinite(x + y + theta + t) and not all(map(math.isfinite, (x, y, theta, t))):
            raise ObservationError(
                "pose_nan", f"pose (x, y, theta, t) = {(x, y, theta, t)} is not finite"
            )
        vx, vy = self.velocity(pose)
        delta, d = goal_features(x, y, theta, *self.goal)
        values += (delta, d, vx, vy)
        return np.array(values, dtype=np.float32)
