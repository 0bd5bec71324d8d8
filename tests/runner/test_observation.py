"""Observation building: RPLIDAR conversion, zones, velocity, goal angle, validation."""

from __future__ import annotations

import math
from fractions import Fraction

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st
from runner_fakes import ring_scan

from advisor_jax.contract import spec, zones
from advisor_jax.runner.errors import ObservationError
from advisor_jax.runner.lidar_zones import rplidar_zones, scan_to_robot_frame, zone_table
from advisor_jax.runner.observation import (
    ObservationBuilder,
    ObservationConfig,
    Pose,
    Scan,
    check_fresh,
    goal_features,
)

BOUNDS = (-2.45, 2.45, -1.5, 1.5)


def builder(**kw) -> ObservationBuilder:
    cfg = dict(min_valid_points=1, bounds=BOUNDS)
    cfg.update(kw)
    return ObservationBuilder(ObservationConfig(**cfg), (1.0, 0.5))


def one_point(cw_deg: float, mm: float = 500.0, **kw) -> np.ndarray:
    """Zones of a scan with a single valid reading."""
    return builder(**kw).zones(Scan(np.array([[15.0, cw_deg, mm]]), 0.0))


def zone_of(p: np.ndarray) -> list[int]:
    return np.flatnonzero(p < 1.0).tolist()


@pytest.mark.parametrize(
    ("cw_deg", "zone"),
    [
        (270.0, 0),  # clockwise 270° = +90° CCW: left, zone 0 (67.5°, 90°]
        (-90.0, 0),
        (90.0, 8),  # -90°: right, zone 8 (-112.5°, -90°]
        (89.9, 7),  # -89.9°: zone 7 (-90°, -67.5°]
        (0.1, 4),  # -0.1°: just right of forward
        (359.9, 3),  # +0.1°: just left of forward
        (180.0, 12),  # ±180°: straight back, one zone whichever way it is written
        (-180.0, 12),
        (540.0, 12),
        (179.9, 11),  # -179.9°
        (180.1, 12),  # +179.9°
    ],
)
def test_rplidar_angles_land_in_documented_zones(cw_deg, zone):
    p = one_point(cw_deg)
    assert zone_of(p) == [zone]
    assert p[zone] == np.float32(0.5)


def test_zone_bounds_match_spec():
    """Every zone's interior, mapped through the clockwise convention, lands in that zone."""
    for k in range(16):
        low, high = spec.zone_bounds_deg(k)
        for ccw in (low + 0.01, 0.5 * (low + high), high - 0.01):
            assert zone_of(one_point(-ccw)) == [k]


def test_units_offset_and_clipping():
    # 640 mm with the body edge 0.22 m from the lidar: 0.42 m of free distance.
    assert one_point(0.0, 640.0, range_offset=0.22)[4] == np.float32(0.42)
    assert one_point(0.0, 100.0, range_offset=0.22)[4] == 0.0  # inside the body: 0
    assert one_point(0.0, 5000.0)[4] == 1.0  # beyond the cutoff: max range
    assert one_point(0.0, 1500.0, max_range=2.0)[4] == np.float32(1.5)


def test_mount_yaw():
    # A lidar mounted back to front: its 0° mark looks backwards (zone 12) and its
    # clockwise 90° mark looks left (+90°: zone 0).
    assert zone_of(one_point(0.0, mount_yaw_deg=180.0)) == [12]
    assert zone_of(one_point(90.0, mount_yaw_deg=180.0)) == [0]
    assert zone_of(one_point(0.0, mount_yaw_deg=90.0)) == [0]


def test_min_per_zone_invalid_dropped_empty_is_max():
    pts = np.array(
        [
            [15, 1.0, 800.0],  # zone 4
            [15, 2.0, 300.0],  # zone 4: the minimum
            [0, 3.0, 0.0],  # invalid (0 mm): must not read 0 m
            [15, 3.5, 0.0],
            [3, 4.0, 200.0],  # low quality: dropped when min_quality = 5
        ]
    )
    p = builder().zones(Scan(pts, 0.0))
    np.testing.assert_array_equal(p, np.where(np.arange(16) == 4, 0.2, 1.0).astype(np.float32))
    p = builder(min_quality=5).zones(Scan(pts, 0.0))
    assert p[4] == np.float32(0.3) and p.dtype == np.float32
    p = builder(min_range=0.25).zones(Scan(pts, 0.0))  # 200 mm: a hit on the chassis
    assert p[4] == np.float32(0.3)


def test_ring_scan_fixture():
    d = np.linspace(0.3, 1.1, 16)
    p = builder(range_offset=0.2).zones(ring_scan(d, 0.0))
    np.testing.assert_allclose(p, np.clip(d - 0.2, 0.0, 1.0), atol=1e-7)


def rule_zone(cw_deg: float, mount_yaw_deg: float) -> int:
    """spec.py's zone rule in exact rational arithmetic: zone k holds robot-frame angles a
    with start - w (k + 1) < a <= start - w k (mod 360), a = mount_yaw - clockwise angle."""
    ccw = Fraction(mount_yaw_deg) - Fraction(cw_deg)
    start, width = Fraction(spec.ZONE_START_DEG), Fraction(spec.ZONE_WIDTH_DEG)
    return math.floor((start - ccw) / width) % spec.N_ZONES


def rule_zones(points, kept, mount_yaw_deg, offset, max_range=1.0) -> np.ndarray:
    """Zones of RPLIDAR points by a plain loop over the exact rule; free distance in the
    generic path's float64 operations (mm * 1e-3, minus offset, clipped)."""
    ref = np.full(16, max_range)
    for (_, deg, mm), keep in zip(points.tolist(), kept, strict=True):
        if keep:
            k = rule_zone(deg, mount_yaw_deg)
            ref[k] = min(ref[k], min(max(mm * 1e-3 - offset, 0.0), max_range))
    return ref


@settings(max_examples=60, deadline=None)
@given(
    seed=st.integers(0, 2**31 - 1),
    n=st.integers(1, 300),
    yaw=st.sampled_from([0.0, 180.0, -37.5, 22.5, 1 / 64]),
    offset=st.sampled_from([0.0, 0.22]),
)
def test_car_zone_path_follows_the_rule_and_matches_the_simulator(seed, n, yaw, offset):
    """The car's reduction equals the exact rule everywhere (exact boundaries, ±180°, angles
    beyond [0, 360), off the 1/64° grid), and the simulator's on every scan that has no
    reading exactly on a zone boundary off the 1/64° grid (tests/contract/test_zones.py:
    on the grid, everywhere)."""
    rng = np.random.default_rng(seed)
    deg = rng.uniform(-400.0, 400.0, n)  # off any boundary (a double hits one with p ~ 0)
    grid = rng.random(n) < 0.5
    deg[grid] = np.floor(deg[grid] * 64) / 64  # the RPLIDAR's 1/64° steps
    on_boundary = rng.random(n) < 0.2
    deg[on_boundary] = rng.integers(-32, 32, on_boundary.sum()) * 22.5 + (yaw - 90.0) % 22.5
    mm = np.floor(rng.uniform(0.0, 1500.0, n) * 4) / 4
    mm[rng.random(n) < 0.2] = 0.0
    points = np.stack([np.full(n, 15.0), deg, mm], 1)
    kept = (rng.random(n) < 0.9) & (mm > 0)
    car = rplidar_zones(points, ~kept, mount_yaw_deg=yaw, range_offset=offset)
    np.testing.assert_array_equal(car, rule_zones(points, kept, yaw, offset))
    # Exactly on a boundary: the drawn ones, and 1/64° grid points that land on one (for a
    # yaw on the grid, every boundary is a grid point: e.g. 157.5° with yaw 0).
    in_zone_widths = (deg - yaw + 90.0) / spec.ZONE_WIDTH_DEG
    exactly_on = on_boundary | (in_zone_widths == np.round(in_zone_widths))
    away = kept & ~exactly_on
    angles, ranges = scan_to_robot_frame(points, yaw)
    np.testing.assert_array_equal(
        rplidar_zones(points, ~away, mount_yaw_deg=yaw, range_offset=offset),
        zones.reduce_to_zones(angles, ranges, away, range_offset=offset),
    )


@pytest.mark.parametrize("yaw", [0.0, 180.0, -90.0, -37.5, 1 / 64])
def test_zone_table(yaw):
    """Every 1/64° tick's zone is the simulator's ``zone_index`` at the tick's middle, and
    ticks at and around each boundary follow the exact rule."""
    table = zone_table(yaw)
    ticks = np.arange(len(table))
    mid_angles, _ = scan_to_robot_frame(np.stack([ticks * 0.0, (ticks + 0.5) / 64, ticks], 1), yaw)
    np.testing.assert_array_equal(table, zones.zone_index(mid_angles))
    start = round((spec.ZONE_START_DEG - yaw) * 64)
    for boundary in range((-start) % 1440, len(table), 1440):
        for n in (boundary - 1, boundary, boundary + 1):
            assert table[n % len(table)] == rule_zone(n / 64, yaw), n


def test_exact_boundaries_follow_the_rule_in_both():
    """157.5° clockwise is -157.5° CCW, the top of zone 11 (-180°, -157.5°]; in radians it
    rounds below the boundary, which zone_index's snap to the 1/64° grid undoes."""
    assert rule_zone(157.5, 0.0) == 11
    assert zone_table(0.0)[157 * 64 + 32] == 11
    assert zone_of(one_point(157.5)) == [11]
    assert int(zones.zone_index(np.radians(np.array([-157.5])))[0]) == 11


def test_mount_yaw_on_the_rplidar_grid():
    ObservationConfig(mount_yaw_deg=2.296875)  # 147 / 64
    with pytest.raises(ValueError, match=r"multiple of 1/64 degree .* e\.g\. 2\.296875"):
        ObservationConfig(mount_yaw_deg=2.3)


@pytest.mark.parametrize(
    ("points", "reason"),
    [
        (np.array([[15.0, np.nan, 500.0]]), "scan_nan"),
        (np.array([[15.0, 10.0, np.inf]]), "scan_nan"),
        (np.zeros((5, 2)), "scan_format"),
        (np.zeros((0, 3)), "scan_empty"),
        ([("a", "b", "c")], "scan_format"),
        (np.array([[15.0, 10.0, -5.0]]), "scan_format"),
        (np.array([[15.0, 1e308, 1e308]] * 3), "scan_format"),
        (np.array([[15.0, 1e13, 500.0]] * 3), "scan_format"),
        (np.array([[15.0, 10.0, 500.0]] * 30 + [[15.0, 20.0, -1.0]]), "scan_format"),
        (np.array([[0.0, 10.0, 0.0]] * 10), "scan_empty"),
    ],
)
def test_bad_scans(points, reason):
    with pytest.raises(ObservationError) as e, np.errstate(over="ignore"):
        builder().zones(Scan(points, 0.0))
    assert e.value.reason == reason


def test_too_few_valid_readings():
    pts = np.array([[15.0, a, 500.0 if a < 30 else 0.0] for a in range(200)])
    with pytest.raises(ObservationError, match="30 valid readings of 200 .need 50"):
        builder(min_valid_points=50).zones(Scan(pts, 0.0))


def test_list_of_tuples_accepted():
    p = builder().zones(Scan([(15, 90.0, 700.0), (15, 270.0, 400.0)], 0.0))
    assert p[8] == np.float32(0.7) and p[0] == np.float32(0.4)


def _pose(x, y, theta, t):
    return Pose(x, y, theta, t, t)


def test_finite_difference_velocity():
    b = builder()
    assert b.velocity(_pose(0.0, 0.0, 0.0, 10.0)) == (0.0, 0.0)  # first pose: at rest
    vx, vy = b.velocity(_pose(0.1, -0.05, 1.0, 10.05))
    assert vx == pytest.approx(2.0) and vy == pytest.approx(-1.0)
    # The same datagram seen again (tracker slower than the loop): keep the velocity.
    assert b.velocity(_pose(0.1, -0.05, 1.0, 10.05)) == (vx, vy)
    vx, vy = b.velocity(_pose(0.1, 0.05, 1.0, 10.15))  # world frame, independent of θ
    assert vx == pytest.approx(0.0) and vy == pytest.approx(1.0)


def test_pose_glitches_and_recovery():
    b = builder(max_speed=3.0)
    b.velocity(_pose(0.0, 0.0, 0.0, 1.0))
    with pytest.raises(ObservationError) as e:
        b.velocity(_pose(1.0, 0.0, 0.0, 1.05))  # 20 m/s: a tracker glitch
    assert e.value.reason == "pose_jump"
    assert b.velocity(_pose(1.01, 0.0, 0.0, 1.1)) == pytest.approx((0.2, 0.0))  # recovered
    with pytest.raises(ObservationError) as e:
        b.velocity(_pose(1.0, 0.1, 0.0, 1.1))  # same timestamp, different place
    assert e.value.reason == "pose_time"
    with pytest.raises(ObservationError) as e:
        b.velocity(_pose(1.0, 0.1, 0.0, 0.5))  # time went backwards
    assert e.value.reason == "pose_time"
    assert b.velocity(_pose(1.0, 0.15, 0.0, 0.55)) == pytest.approx((0.0, 1.0))


@pytest.mark.parametrize(
    ("pose", "goal", "delta", "d"),
    [
        ((0, 0, 0), (1, 0), 0.0, 1.0),
        ((0, 0, 0), (0, 2), math.pi / 2, 2.0),  # goal on the left: δ > 0
        ((0, 0, 0), (0, -2), -math.pi / 2, 2.0),
        ((0, 0, 0), (-1, 0), -math.pi, 1.0),  # straight behind: -π, never +π
        ((0, 0, 3 * math.pi / 4), (1, -1), -math.pi, math.sqrt(2)),
        ((0, 0, -3 * math.pi / 4), (0, 1), -3 * math.pi / 4, 1.0),  # 5π/4 wraps
        ((1, 1, 0.5), (1, 1), -0.5, 0.0),  # on the goal
        ((0, 0, 0), (-1, 1e-9), math.pi - 1e-9, 1.0),
    ],
)
def test_goal_features(pose, goal, delta, d):
    got_delta, got_d = goal_features(*pose, *goal)
    assert got_delta == pytest.approx(delta, abs=1e-12) and got_d == pytest.approx(d)
    assert -math.pi <= got_delta < math.pi


def test_build_layout():
    b = ObservationBuilder(ObservationConfig(range_offset=0.2, bounds=BOUNDS), (1.0, 0.5))
    zones_m = np.linspace(0.3, 1.1, 16)
    obs0 = b.build(ring_scan(zones_m, 0.0), Pose(0.0, 0.0, math.pi / 2, 5.0, 0.0))
    obs1 = b.build(ring_scan(zones_m, 0.0), Pose(0.0, 0.05, math.pi / 2, 5.1, 0.0))
    assert obs1.dtype == np.float32 and obs1.shape == (20,)
    np.testing.assert_allclose(obs1[:16], np.clip(zones_m - 0.2, 0, 1), atol=1e-7)
    # heading +y, goal at (1, 0.45) relative: to the right ⇒ δ < 0
    assert obs1[16] == np.float32(math.atan2(0.45, 1.0) - math.pi / 2)
    assert obs1[17] == np.float32(math.hypot(1.0, 0.45))
    assert tuple(obs0[18:]) == (0.0, 0.0) and obs1[18:] == pytest.approx([0.0, 0.5])


def test_build_matches_reference():
    """The builder's fast path equals the observation assembled from the documented pieces:
    the exact zone rule, the finite-difference velocity and goal_features."""
    rng = np.random.default_rng(3)
    cfg = ObservationConfig(range_offset=0.22, mount_yaw_deg=180.0, min_quality=5.0,
                            min_range=0.15, bounds=BOUNDS)  # fmt: skip
    b = ObservationBuilder(cfg, (1.5, -0.5))
    prev = None
    for step in range(50):
        deg = np.floor(rng.uniform(0.0, 360.0, 200) * 64) / 64
        deg[:20] = rng.integers(0, 16, 20) * 22.5  # on zone boundaries
        mm = np.floor(rng.uniform(0.0, 1500.0, 200) * 4) / 4
        mm[rng.random(200) < 0.1] = 0.0
        quality = rng.integers(0, 16, 200).astype(float)
        points = np.stack([quality, deg, mm], 1)
        pose = Pose(0.1 * step, -0.02 * step, 0.3, 0.05 * step, 0.0)
        obs = b.build(Scan(points, 0.0), pose)
        keep = (mm > 150.0) & (quality >= 5.0)
        ref_zones = rule_zones(points, keep, 180.0, 0.22)
        np.testing.assert_array_equal(obs[:16], ref_zones.astype(np.float32))
        delta, d = goal_features(pose.x, pose.y, pose.theta, 1.5, -0.5)
        v = (0.0, 0.0) if prev is None else ((pose.x - prev.x) / 0.05, (pose.y - prev.y) / 0.05)
        np.testing.assert_array_equal(obs[16:], np.array([delta, d, *v], np.float32))
        prev = pose


def test_bad_pose_and_goal():
    b = builder()
    with pytest.raises(ObservationError) as e:
        b.build(ring_scan(0.5, 0.0), Pose(np.nan, 0.0, 0.0, 1.0, 0.0))
    assert e.value.reason == "pose_nan"
    for bad in (np.inf, -np.inf):
        with pytest.raises(ObservationError) as e:
            builder().build(ring_scan(0.5, 0.0), Pose(0.0, 0.0, bad, 1.0, 0.0))
        assert e.value.reason == "pose_nan"
    # theta + t overflows the fast check's sum, but every value is finite: a valid pose
    obs = builder().build(ring_scan(0.5, 0.0), Pose(0.0, 0.0, 1e308, 1e308, 0.0))
    assert np.isfinite(obs).all()
    for goal in ((3.0, 0.0), (0.0, -1.6), (np.nan, 0.0)):
        with pytest.raises(ObservationError) as e:
            ObservationBuilder(ObservationConfig(bounds=BOUNDS), goal)
        assert e.value.reason == "goal_outside"
    with pytest.raises(ObservationError, match=r"goal \(3, 0\) is outside the arena bounds"):
        ObservationBuilder(ObservationConfig(bounds=BOUNDS), (3.0, 0.0))
    with pytest.raises(ValueError, match="max_speed"):
        ObservationConfig(max_speed=0.0)


def test_check_fresh():
    check_fresh("scan", 9.8, 10.0, 0.3)
    with pytest.raises(ObservationError, match="scan is 400 ms old .limit 300 ms") as e:
        check_fresh("scan", 9.6, 10.0, 0.3)
    assert e.value.reason == "stale_scan"
    with pytest.raises(ObservationError) as e:
        check_fresh("pose", float("nan"), 10.0, 0.3)
    assert e.value.reason == "stale_pose"
