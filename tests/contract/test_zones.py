"""One zone reduction: the car's (runner/lidar_zones.py) equals the contract's, which the
simulator runs (contract/zones.py), on every reading the RPLIDAR can give.

The car sees angles on the RPLIDAR's 1/64° grid (``raw_angle / 64``) and distances on its
quarter-millimetre grid (``raw_distance / 4``). A reduction is a zone per reading, a free
distance per reading and a minimum per zone. Proven exhaustively:

* zones: every robot-frame angle of the grid that a mount yaw of at most one turn and a
  reading can make, the contract's ``zone_index`` against ``spec.py``'s rule in integer
  arithmetic, and the car's tick table against the same rule for several mount yaws;
* free distances: every distance of the grid up to 16.4 m, the car's ``free_distances``
  against the contract's ``clip(range - offset, 0, max_range)``, both non-decreasing in the
  distance, so that the car's minimum over raw millimetres first gives the same bits.

Random scans then check the whole reductions against each other and against a plain loop.
"""

from __future__ import annotations

import numpy as np
import pytest

from advisor_jax.contract import spec, zones
from advisor_jax.runner.lidar_zones import (
    free_distances,
    rplidar_zones,
    scan_to_robot_frame,
    zone_table,
)

GRID = 64  # RPLIDAR angle steps per degree
START, WIDTH = round(spec.ZONE_START_DEG * GRID), round(spec.ZONE_WIDTH_DEG * GRID)
YAWS = (0.0, 90.0, -90.0, 180.0, 22.5, -37.5, 1 / 64, 359.984375, -359.984375)


def rule(ccw_steps: np.ndarray) -> np.ndarray:
    """spec.py's zone of robot-frame angles ``ccw_steps / 64`` degrees, in integers: zone k
    holds start - w (k + 1) < a <= start - w k (mod 360)."""
    return ((START - ccw_steps) // WIDTH) % spec.N_ZONES


def test_contract_zone_index_follows_the_rule_on_every_grid_angle():
    """Robot-frame angle = mount yaw - clockwise reading: with |yaw| <= 360° and readings in
    [0°, 360°) every such angle lies in [-720°, 360°], computed as the car does
    (``np.radians`` of the difference in degrees, exact on the grid)."""
    steps = np.arange(-720 * GRID, 360 * GRID + 1)
    got = zones.zone_index(np.radians(steps / GRID))
    np.testing.assert_array_equal(got, rule(steps))


@pytest.mark.parametrize("yaw", YAWS)
def test_car_tick_table_follows_the_rule(yaw):
    ticks = np.arange(360 * GRID)
    np.testing.assert_array_equal(zone_table(yaw), rule(round(yaw * GRID) - ticks))
    angles, _ = scan_to_robot_frame(np.stack([ticks * 0.0, ticks / GRID, ticks], 1), yaw)
    np.testing.assert_array_equal(zone_table(yaw), zones.zone_index(angles))


@pytest.mark.parametrize("offset", [0.0, 0.22])
def test_free_distances_agree_on_every_grid_distance(offset):
    mm = np.arange(2**16) / 4.0  # the RPLIDAR's quarter millimetres, 0 .. 16383.75
    contract = np.clip(mm * 1e-3 - offset, 0.0, spec.MAX_RANGE)
    car = np.concatenate([
        free_distances([*chunk, np.inf], spec.MAX_RANGE, offset)
        for chunk in mm.reshape(-1, spec.N_ZONES).tolist()
    ])  # fmt: skip
    np.testing.assert_array_equal(car, contract)
    assert np.all(np.diff(contract) >= 0)  # the minimum commutes with the map


@pytest.mark.parametrize("seed", range(6))
def test_whole_reductions_agree_on_grid_scans(seed):
    """Random scans on the grids, a fifth of their readings exactly on zone boundaries, some
    dropped or at zero distance: the car's reduction equals the contract's bit for bit and
    a plain loop over the rule."""
    rng = np.random.default_rng(seed)
    n, yaw, offset = 300, YAWS[seed % len(YAWS)], (0.0, 0.22)[seed % 2]
    ticks = rng.integers(0, 360 * GRID, n)
    on_edge = rng.random(n) < 0.2
    ticks[on_edge] = (rng.integers(0, 16, on_edge.sum()) * WIDTH + round(yaw * GRID)
                      - START) % (360 * GRID)  # fmt: skip
    mm = rng.integers(0, 6000, n) / 4.0
    points = np.stack([np.full(n, 15.0), ticks / GRID, mm], 1)
    kept = (rng.random(n) < 0.9) & (mm > 0)
    car = rplidar_zones(points, ~kept, mount_yaw_deg=yaw, range_offset=offset)
    angles, ranges = scan_to_robot_frame(points, yaw)
    contract = zones.reduce_to_zones(angles, ranges, kept, range_offset=offset)
    np.testing.assert_array_equal(car, contract)
    loop = np.full(spec.N_ZONES, spec.MAX_RANGE)
    for t, r, keep in zip(ticks, mm, kept, strict=True):
        if keep:
            k = rule(np.array([round(yaw * GRID) - t]))[0]
            loop[k] = min(loop[k], min(max(r * 1e-3 - offset, 0.0), spec.MAX_RANGE))
    np.testing.assert_array_equal(contract, loop)


def test_non_finite_and_dropped_readings_leave_a_zone_empty():
    angles = np.array([0.1, np.nan, 0.2, 0.3])
    ranges = np.array([np.inf, 0.5, -1.0, 0.4])
    got = zones.reduce_to_zones(angles, ranges, np.array([True, True, True, False]))
    np.testing.assert_array_equal(got, np.full(spec.N_ZONES, spec.MAX_RANGE))
