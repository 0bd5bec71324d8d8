"""Lidar zones on the car: RPLIDAR readings (1/64° clockwise ticks, mm) → the 16 zones.

The zone of a reading follows ``contract/spec.py``'s rule exactly, through an integer table
of the 23040 ticks of a turn (``zone_table``); per cycle, ``zone_minima_mm`` takes each
zone's minimum in a handful of numpy calls (the control cycle's latency budget, see
``experiments/bench_runner.py``) and ``free_distances`` turns them into free distances the
way the simulator does (``contract.zones.reduce_to_zones``). ``rplidar_zones`` is the
whole reduction as one call, for tests and tools.
"""

from __future__ import annotations

import math

import numpy as np

from advisor_jax.contract import spec

TICKS_PER_DEGREE = 64
"""RPLIDAR angles come in 1/64° steps (the ``rplidar`` package: ``raw_angle / 64``)."""
TICKS_PER_TURN = 360 * TICKS_PER_DEGREE
_ZONE_START_TICKS = round(spec.ZONE_START_DEG * TICKS_PER_DEGREE)
_ZONE_WIDTH_TICKS = round(spec.ZONE_WIDTH_DEG * TICKS_PER_DEGREE)
assert _ZONE_START_TICKS == spec.ZONE_START_DEG * TICKS_PER_DEGREE, "zone start off the tick grid"
assert _ZONE_WIDTH_TICKS * spec.N_ZONES == TICKS_PER_TURN, "zone width off the tick grid"

# Bound once: the per-cycle code below calls them directly.
_multiply, _floor, _putmask, _minimum_at = np.multiply, np.floor, np.putmask, np.minimum.at
_TICKS = np.full((), float(TICKS_PER_DEGREE))  # 0-d: no Python-number conversion per call
_EMPTY_ZONES = np.full(spec.N_ZONES + 1, np.inf)


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
