"""Action scaling, differential and Ackermann conversion (hand-computed cases)."""

from __future__ import annotations

import math

import numpy as np
import pytest

from advisor_jax.runner.drive import (
    AckermannCommand,
    AckermannDrive,
    DiffCommand,
    DiffDrive,
    make_drive,
    to_physical,
)


def test_to_physical_scales_and_validates():
    assert to_physical(np.array([0.5, -0.25], np.float32), 1.0, 2.0) == (0.5, -0.5)
    assert to_physical((1.0, 1.0), 0.8, 1.5) == (0.8, 1.5)
    with pytest.raises(ValueError, match="not finite"):
        to_physical((np.nan, 0.0), 1.0, 1.0)
    with pytest.raises(ValueError, match="outside"):
        to_physical((1.2, 0.0), 1.0, 1.0)


def test_differential():
    drive = DiffDrive(track_width=0.4)
    assert drive.command(0.5, 0.0) == DiffCommand(0.5, 0.5)  # straight
    left, right = drive.command(0.5, 1.0)  # turn left (CCW): right wheel faster
    assert (left, right) == pytest.approx((0.3, 0.7))
    assert drive.command(0.0, -2.0) == pytest.approx((0.4, -0.4))  # spin right in place
    capped = DiffDrive(track_width=0.4, max_wheel_speed=0.5).command(0.5, 1.0)
    assert capped == pytest.approx((0.3 * 0.5 / 0.7, 0.5))  # same curvature, right at cap
    assert capped[1] / capped[0] == pytest.approx(0.7 / 0.3)


def test_ackermann_cases():
    car = AckermannDrive(wheelbase=0.25, max_steering=0.5)
    assert car.command(1.0, 0.0) == AckermannCommand(1.0, 0.0)  # straight
    speed, steer = car.command(1.0, 1.0)  # left turn: positive steering
    assert speed == 1.0 and steer == pytest.approx(math.atan(0.25))
    assert car.command(1.0, -1.0).steering == pytest.approx(-math.atan(0.25))
    # The bicycle model reproduces the commanded yaw rate when not clipped.
    assert speed * math.tan(steer) / 0.25 == pytest.approx(1.0)
    # Clipping: atan(0.25 * 2 / 0.1) = 1.37 rad > 0.5 rad lock.
    assert car.command(0.1, 2.0) == AckermannCommand(0.1, 0.5)
    assert car.command(0.1, -2.0) == AckermannCommand(0.1, -0.5)


def test_ackermann_at_standstill():
    """V = 0: full lock towards the sign of ω (the v → 0⁺ limit), straight if ω = 0."""
    car = AckermannDrive(wheelbase=0.25, max_steering=0.4)
    assert car.command(0.0, 0.3) == AckermannCommand(0.0, 0.4)
    assert car.command(0.0, -0.3) == AckermannCommand(0.0, -0.4)
    assert car.command(0.0, 0.0) == AckermannCommand(0.0, 0.0)
    assert car.command(1e-9, 0.3).steering == pytest.approx(0.4)  # continuous at 0⁺
    with pytest.raises(ValueError, match="forwards"):
        car.command(-0.1, 0.0)


def test_bad_geometry_and_round_trip():
    with pytest.raises(ValueError, match="track_width"):
        DiffDrive(track_width=0.0)
    with pytest.raises(ValueError, match="max_steering"):
        AckermannDrive(wheelbase=0.25, max_steering=2.0)
    with pytest.raises(ValueError, match="wheelbase"):
        AckermannDrive(wheelbase=float("nan"), max_steering=0.4)
    for drive in (DiffDrive(0.3, 1.0), AckermannDrive(0.26, 0.4)):
        assert make_drive(drive.describe()) == drive
    with pytest.raises(ValueError, match="unknown drive kind"):
        make_drive({"kind": "tank"})
