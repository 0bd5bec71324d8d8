"""Lidar scan → 16 proximity zones (paper §5.2): the one rule of simulator and car.

The paper's car reduces the ~200 readings of an RPLIDAR A2 turn to 16 distances by taking
the minimum reading in each angular zone. The simulated ``physical`` arena does the same to
its 200 MuJoCo rangefinder beams by calling ``reduce_to_zones`` with ``xp=jax.numpy``. The
car (``runner/lidar_zones.py``) computes the same function for its control cycle's latency
budget: a table of each 1/64° tick's zone and a scatter-minimum over raw millimetres.
tests/contract/test_zones.py proves the two equal on every reading the RPLIDAR can give:
every angle of its 1/64° grid, every distance of its quarter-millimetre grid. The zone
definition is in ``spec.py``.

Written against a generic array module ``xp`` (numpy or jax.numpy) with no data-dependent
Python control flow, so it is jit- and vmap-safe.
"""

from __future__ import annotations

import math
from typing import Any

import numpy as np

from advisor_jax.contract import spec

assert spec.N_ZONES & (spec.N_ZONES - 1) == 0, "zone_index wraps with a bit mask"
ZONE_START_RAD = math.radians(spec.ZONE_START_DEG)
GRID_PER_DEGREE = 64
"""Angles are resolved to 1/64° (the RPLIDAR's angle step, ``raw_angle / 64``): an angle
within ``GRID_SNAP`` steps of a grid point is that grid point."""
GRID_PER_RAD = GRID_PER_DEGREE * 180.0 / math.pi
GRID_PER_ZONE = round(spec.ZONE_WIDTH_DEG * GRID_PER_DEGREE)
assert GRID_PER_ZONE == spec.ZONE_WIDTH_DEG * GRID_PER_DEGREE, "zone width off the 1/64° grid"
assert round(spec.ZONE_START_DEG * GRID_PER_DEGREE) == spec.ZONE_START_DEG * GRID_PER_DEGREE
GRID_SNAP = 1e-6


def zone_index(angles_rad: Any, xp: Any = np) -> Any:
    """Zone (0..15) of each robot-frame beam angle (radians, CCW positive, 0 = forward).

    Zone k holds the angles a with start - w (k + 1) < a <= start - w k (mod 360°;
    ``spec.zone_bounds_deg``). The position is measured in 1/64° steps below zone 0's upper
    edge and snapped to the grid (``GRID_SNAP``), so that a reading of the RPLIDAR's grid
    that lies exactly on a boundary follows the half-open rule whatever the rounding of its
    conversion to radians (157.5° clockwise is the top of zone 11, not zone 10). The
    simulator's beams lie at least 0.45° from every boundary (``envs.mjcf``), where the
    snap changes nothing. The mapping wraps, so +180° and -180° land in the same zone; any
    finite angle of magnitude below ~10^8 rad (where the turn count leaves int32) is
    accepted.
    """
    steps = (ZONE_START_RAD - angles_rad) * GRID_PER_RAD
    nearest = xp.round(steps)
    steps = xp.where(xp.abs(steps - nearest) < GRID_SNAP, nearest, steps)
    k = xp.floor(steps / GRID_PER_ZONE).astype(xp.int32)
    return k & (spec.N_ZONES - 1)  # = k mod 16, negative k included (two's complement)


def reduce_to_zones(
    angles_rad: Any,
    ranges_m: Any,
    valid: Any | None = None,
    *,
    max_range: float = spec.MAX_RANGE,
    range_offset: float = 0.0,
    xp: Any = np,
) -> Any:
    """Minimum free distance per zone.

    Args:
      angles_rad: [beams] robot-frame beam angles (CCW positive, 0 = forward).
      ranges_m: [beams] measured ranges from the lidar origin, metres.
      valid: optional [beams] bool; readings that are invalid, non-finite or <= 0 are
        dropped whatever this says.
      max_range: value of an empty zone, and upper clip of every zone.
      range_offset: subtracted from every range before the minimum (the distance from the
        lidar origin to the body edge), so that zones read free distance like the sonars.
      xp: array module, ``numpy`` or ``jax.numpy``.

    Returns:
      [16] zone distances in [0, max_range], in the sonar-ring order of ``spec``.
    """
    angles_rad = xp.asarray(angles_rad)
    ranges_m = xp.asarray(ranges_m)
    ok = xp.isfinite(ranges_m) & xp.isfinite(angles_rad) & (ranges_m > 0)
    if valid is not None:
        ok = ok & xp.asarray(valid, dtype=bool)
    safe = xp.where(ok, ranges_m, max_range + range_offset)
    free = xp.clip(safe - range_offset, 0.0, max_range)
    idx = zone_index(xp.where(xp.isfinite(angles_rad), angles_rad, 0.0), xp=xp)
    member = (idx[:, None] == xp.arange(spec.N_ZONES)[None, :]) & ok[:, None]  # [beams, 16]
    return xp.min(xp.where(member, free[:, None], max_range), axis=0)
