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

The zones are the simulator's (``zones.reduce_to_zones``, which the ``physical`` arena runs on
its beams): tests/runner checks that both give the same bits on any scan without a reading
exactly on a zone boundary, where the car follows spec.py's rule exactly and the simulator's
float radians may round to the neighbouring zone (its beams never lie on one).

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

TICKS_PER_DEGREE = 64
"""RPLIDAR angles come in 1/64° steps (the ``rplidar`` package: ``raw_angle / 64``)."""
TICKS_PER_TURN = 360 * TICKS_PER_DEGREE
_ZONE_START_TICKS = round(spec.ZONE_START_DEG * TICKS_PER_DEGREE)
_ZONE_WIDTH_TICKS = round(spec.ZONE_WIDTH_DEG * TICKS_PER_DEGREE)
assert _ZONE_START_TICKS == spec.ZONE_START_DEG * TICKS_PER_DEGREE, "zone start off the tick grid"
assert _ZONE_WIDTH_TICKS * spec.N_ZONES == TICKS_PER_TURN, "zone width off the tick grid"
_SCAN_NORM_LIMIT = 1e12
"""A scan whose values have a larger Euclidean norm is refused (scan_format): they are not
degrees and mm (a turn's norm is ~10^5), and angles stay far from int64 1/64° ticks' limit."""


# Bound once: the per-cycle code below calls them directly (bench_runner.py's budget).
_vdot, _multiply, _floor = np.vdot, np.multiply, np.floor
_less, _less_equal = np.less, np.less_equal
_putmask, _count_nonzero, _minimum_at = np.putmask, np.count_nonzero, np.minimum.at
_TICKS = np.full((), float(TICKS_PER_DEGREE))  # 0-d: no Python-number conversion per call
_EMPTY_ZONES = np.full(spec.N_ZONES + 1, np.inf)


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


def scan_to_robot_frame(
    points: np.ndarray, mount_yaw_deg: float = 0.0
) -> tuple[np.ndarray, np.ndarray]:
    """[n, 3] RPLIDAR points → (robot-frame CCW angles [n] rad, ranges [n] m)."""
    angles = np.radians(mount_yaw_deg - points[:, 1])  # clockwise degrees → CCW radians
    return angles, points[:, 2] * 1e-3


def mount_yaw_ticks(mount_yaw_deg: float) -> int:
    """The lidar mount's yaw in 1/64° ticks; ValueError unless it lies on that grid."""
    ticks = float(mount_yaw_deg) * TICKS_PER_DEGREE  # exact: a power-of-two scaling
    if not (math.isfinite(ticks) and ticks.is_integer()):
        nearest = round(ticks) / TICKS_PER_DEGREE if math.isfinite(ticks) else 0.0
        raise ValueError(
            f"mount_yaw_deg={mount_yaw_deg!r} must be a multiple of 1/64 degree (the RPLIDAR's "
            f"angle step), e.g. {nearest!r}"
        )
    return int(ticks)


def zone_table(mount_yaw_deg: float = 0.0) -> np.ndarray:
    """[23040] zone of each 1/64° tick of a clockwise RPLIDAR angle (``spec.py``'s rule).

    A reading at clockwise angle ``a`` (degrees) points at robot-frame angle ``mount_yaw - a``
    (CCW), which lies in zone k iff ``22.5 k <= a + 90 - mount_yaw < 22.5 (k + 1)`` (mod 360;
    ``spec.zone_bounds_deg``). With ``mount_yaw`` on the 1/64° grid every zone boundary is a
    tick, so the zone of any ``a`` is the zone of its tick ``floor(64 a) mod 23040``: this
    table, computed in integers, is the rule exactly, for every float ``a`` (exact boundaries
    included; the float radians of ``zones.zone_index`` round there, e.g. 157.5° clockwise
    lands in zone 10 instead of 11, and the simulator's beams avoid boundaries for that
    reason; tests/runner checks both agree everywhere else).
    """
    yaw_ticks = mount_yaw_ticks(mount_yaw_deg)
    ticks = np.arange(TICKS_PER_TURN, dtype=np.int64) + (_ZONE_START_TICKS - yaw_ticks)
    return (ticks // _ZONE_WIDTH_TICKS % spec.N_ZONES).astype(np.intp)


def zone_minima_mm(points: np.ndarray, dropped: np.ndarray, table: np.ndarray) -> list[float]:
    """Per-zone minimum raw distance (mm; inf for an empty zone) of a checked RPLIDAR scan.

    Returns 17 values: the 16 zones, then a 17th slot that collects the ``dropped`` readings
    (so its minimum is negative exactly when a dropped reading had a negative distance).
    ``points`` must be finite with |values| <= 1e12 (``ObservationBuilder`` checks it).
    Written for the control cycle's latency budget (``bench_runner.py``), where numpy's
    per-call overhead dominates: eight numpy calls for the whole scan.
    """
    index = _multiply(points[:, 1], _TICKS)
    _floor(index, out=index)
    index = table.take(index.astype(np.intp), mode="wrap")  # tick mod 23040 → zone
    _putmask(index, dropped, spec.N_ZONES)
    mm = _EMPTY_ZONES.copy()
    _minimum_at(mm, index, points[:, 2])
    return mm.tolist()


def free_distances(minima_mm: list[float], max_range: float, range_offset: float) -> list[float]:
    """The 16 zone values of ``zone_minima_mm``: ``clip(mm * 1e-3 - offset, 0, max_range)``,
    the generic path's ``clip(range_m - offset, 0, max_range)`` of ``range_m = mm * 1e-3`` in
    the same float64 operations. Each step is non-decreasing in ``mm``, so taking the
    minimum over raw millimetres first gives the same bits; an empty zone (inf) reads
    ``max_range``."""
    return [
        0.0 if (v := mm * 1e-3 - range_offset) <= 0.0 else (v if v < max_range else max_range)
        for mm in minima_mm[: spec.N_ZONES]
    ]


def rplidar_zones(
    points: np.ndarray,
    dropped: np.ndarray,
    *,
    mount_yaw_deg: float = 0.0,
    max_range: float = spec.MAX_RANGE,
    range_offset: float = 0.0,
) -> np.ndarray:
    """[16] float64 zone distances of a checked RPLIDAR scan (``dropped`` [n] bool marks the
    readings to leave out): what ``ObservationBuilder`` computes each cycle, as one call.

    Equals ``zones.reduce_to_zones(*scan_to_robot_frame(points, mount_yaw_deg), ~dropped,
    ...)`` bit for bit wherever no kept reading lies exactly on a zone boundary, and follows
    ``spec.py``'s rule exactly there too (``zone_table``).
    """
    minima = zone_minima_mm(points, dropped, zone_table(mount_yaw_deg))
    return np.array(free_distances(minima, max_range, range_offset))


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
