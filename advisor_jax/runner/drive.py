"""Normalised actions → physical velocities → motor commands (paper §5.2, §5.3).

The actor outputs (V, ω) with V ∈ [0, 1] and ω ∈ [-1, 1] (``spec.py``). Physically::

    v = V · v_max  (m/s, forward),   w = ω · omega_max  (rad/s, CCW = left)

Differential drive (track width b)::

    left = v - w b / 2,   right = v + w b / 2           (wheel rim speeds, m/s)

scaled down together (same curvature) if either exceeds ``max_wheel_speed``.

Ackermann car, kinematic bicycle model (wheelbase L)::

    yaw rate = v tan(δ_s) / L   ⇒   δ_s = atan(L w / v) = atan2(L w, v)  for v > 0
    δ_s = clip(δ_s, -max_steering, +max_steering)

At v = 0 a car cannot turn on the spot. ``atan2`` gives the limit v → 0⁺ of the formula,
with no division: full lock towards the sign of ω (clipped to ±max_steering) when ω ≠ 0,
straight ahead when ω = 0. So the wheels are already turned the right way when the car
starts to move, and the command is continuous in (v, w). Positive steering turns left.
"""

from __future__ import annotations

import dataclasses
import math
from typing import NamedTuple, Protocol

import numpy as np


class DiffCommand(NamedTuple):
    """Wheel rim speeds (m/s) of a differential drive."""

    left: float
    right: float

    def as_dict(self) -> dict:
        return {"kind": "diff", "left": self.left, "right": self.right}


class AckermannCommand(NamedTuple):
    """Forward speed (m/s) and front-wheel steering angle (rad, positive = left)."""

    speed: float
    steering: float

    def as_dict(self) -> dict:
        return {"kind": "ackermann", "speed": self.speed, "steering": self.steering}


Command = DiffCommand | AckermannCommand


class Drive(Protocol):
    """Turns physical (v m/s, w rad/s) into a motor command."""

    def command(self, v: float, w: float) -> Command: ...

    def describe(self) -> dict: ...


def to_physical(action: np.ndarray, v_max: float, omega_max: float) -> tuple[float, float]:
    """Normalised (V, ω) → (v m/s, w rad/s). Refuses non-finite or out-of-box actions."""
    V, omega = float(action[0]), float(action[1])
    if not (math.isfinite(V) and math.isfinite(omega)):
        raise ValueError(f"action (V, omega) = ({V}, {omega}) is not finite")
    if not (0.0 <= V <= 1.0 and -1.0 <= omega <= 1.0):
        raise ValueError(f"action (V, omega) = ({V}, {omega}) is outside [0, 1] x [-1, 1]")
    return V * v_max, omega * omega_max


@dataclasses.dataclass(frozen=True)
class DiffDrive:
    """Differential drive: ``track_width`` (m) between the wheels."""

    track_width: float
    max_wheel_speed: float | None = None
    """m/s; if set, both wheels are scaled down together so neither exceeds it."""

    def __post_init__(self):
        _check_positive("track_width", self.track_width)
        if self.max_wheel_speed is not None:
            _check_positive("max_wheel_speed", self.max_wheel_speed)

    def command(self, v: float, w: float) -> DiffCommand:
        half = 0.5 * w * self.track_width
        left, right = v - half, v + half
        peak = max(abs(left), abs(right))
        if self.max_wheel_speed is not None and peak > self.max_wheel_speed:
            scale = self.max_wheel_speed / peak
            left, right = left * scale, right * scale
        return DiffCommand(left, right)

    def describe(self) -> dict:
        return {"kind": "diff", **dataclasses.asdict(self)}


@dataclasses.dataclass(frozen=True)
class AckermannDrive:
    """Car-like steering: ``wheelbase`` (m), ``max_steering`` (rad) of the front wheels."""

    wheelbase: float
    max_steering: float

    def __post_init__(self):
        _check_positive("wheelbase", self.wheelbase)
        _check_positive("max_steering", self.max_steering)
        if self.max_steering >= math.pi / 2:
            raise ValueError(f"max_steering={self.max_steering} rad must be below pi/2")

    def command(self, v: float, w: float) -> AckermannCommand:
        if v < 0:
            raise ValueError(f"forward speed v={v} < 0: the policy only drives forwards")
        steering = math.atan2(self.wheelbase * w, v)  # = atan(L w / v); v = 0: ±π/2 or 0
        steering = min(max(steering, -self.max_steering), self.max_steering)
        return AckermannCommand(v, steering)

    def describe(self) -> dict:
        return {"kind": "ackermann", **dataclasses.asdict(self)}


def make_drive(desc: dict) -> DiffDrive | AckermannDrive:
    """Inverse of ``describe()`` (used by replay)."""
    kind = desc.get("kind")
    fields = {k: v for k, v in desc.items() if k != "kind"}
    if kind == "diff":
        return DiffDrive(**fields)
    if kind == "ackermann":
        return AckermannDrive(**fields)
    raise ValueError(f"unknown drive kind {kind!r} (diff or ackermann)")


def _check_positive(name: str, value: float) -> None:
    if not (isinstance(value, int | float) and math.isfinite(value) and value > 0):
        raise ValueError(f"{name}={value!r} must be a positive number")
