"""The observation, action and sensor contract shared by the simulator and the car.

This module is the single place that says what the 20 numbers of an observation and the
2 numbers of an action mean. The simulator (``envs/``), the advisor, the exporter and the
numpy runner on the car all read it. It imports nothing, so the runner stays numpy-only.

Frames and signs (paper §5.3, Fig. 5a; signs fixed by behaviour, see ``advisor.py``):

* World (arena) frame: x to the right, y up, origin at the arena centre, metres.
* Heading θ: angle of the robot's forward axis from world +x, counter-clockwise positive.
* Robot-frame angles: 0 = straight ahead, counter-clockwise positive (left is +90°).

Observation (``OBS_SIZE`` = 20, float32)::

    index  name   unit  meaning
    0..15  P_i    m     proximity: free distance from the sensor along sensor/zone i,
                        clipped to [0, max_range]; "no hit" reads max_range (1.0 m).
                        Order = P3DX sonar ring: i=0 points left (+90°), then clockwise
                        over the front to the right (-90°, i=7), then over the rear
                        back to the left (i=15).
    16     δ      rad   angle from the heading to the goal direction, counter-clockwise
                        positive (goal on the left ⇒ δ > 0), wrapped to [-π, π).
    17     d      m     Euclidean distance from the robot centre to the goal.
    18     v_x    m/s   robot velocity, world frame, x component (last control period).
    19     v_y    m/s   robot velocity, world frame, y component.

No normalisation is applied: the paper feeds raw values and every entry is O(1)
except d (at most the arena diagonal, ≈7 m).

Action (``ACTION_SIZE`` = 2): ``V ∈ [0, 1]`` (× ``V_MAX`` m/s forward speed) and
``ω ∈ [-1, 1]`` (× ω_max rad/s yaw rate, counter-clockwise positive = turn left).
"""

from __future__ import annotations

import math

OBS_SIZE = 20
ACTION_SIZE = 2
N_SENSORS = 16

# Observation layout.
OBS_PROXIMITY = slice(0, 16)
OBS_GOAL_ANGLE = 16
OBS_GOAL_DISTANCE = 17
OBS_VELOCITY = slice(18, 20)
OBS_NAMES = tuple(f"P{i + 1}" for i in range(N_SENSORS)) + ("delta", "d", "v_x", "v_y")
OBS_UNITS = ("m",) * N_SENSORS + ("rad", "m", "m/s", "m/s")

# Action layout and bounds.
ACTION_NAMES = ("V", "omega")
ACTION_LOW = (0.0, -1.0)
ACTION_HIGH = (1.0, 1.0)

# Defaults shared by every arena (paper Table A1 / A3; docs/architecture.md, "Environment").
V_MAX = 1.0  # m/s, Table A1
CONTROL_DT = 0.05  # s, V-REP's default simulation step
# How the simulator moves the robot (envs/motion.py): a kinematic unicycle, or the P3DX's
# body and wheels stepped by MJX. A policy records the model it was trained with; the car
# refuses one it does not know.
MOTION_MODELS = ("kinematic", "mjx")
MAX_RANGE = 1.0  # m, sensor cutoff; "no hit" reads this

# P3DX sonar ring: direction of each sensor's beam in the robot frame (degrees, CCW
# positive, 0 = forward). Front ring 1..8 from left to right, rear ring 9..16 from right
# back to left, as on the Pioneer 3-DX.
SONAR_DIRECTIONS_DEG = (
    90.0, 50.0, 30.0, 10.0, -10.0, -30.0, -50.0, -90.0,
    -90.0, -130.0, -150.0, -170.0, 170.0, 150.0, 130.0, 90.0,
)  # fmt: skip
# Where on the round body each sonar sits (degrees around the body, CCW from forward).
# Equal to the direction, except for the four side-looking sonars, which sit towards the
# front and rear corners as on the P3DX, so that sonars 1/16 and 8/9 see different things.
SONAR_MOUNTS_DEG = (
    65.0, 50.0, 30.0, 10.0, -10.0, -30.0, -50.0, -65.0,
    -115.0, -130.0, -150.0, -170.0, 170.0, 150.0, 130.0, 115.0,
)  # fmt: skip

# Lidar zones (physical arena and the car, paper §5.2): 16 equal sectors of 22.5°, in the
# same order as the sonar ring. Zone k covers robot-frame angles a (CCW, degrees) with
#     90 - 22.5 (k + 1) < a <= 90 - 22.5 k     (mod 360)
# so zone 0 is (67.5°, 90°] (left-front), zone 7 is (-90°, -67.5°] (right-front), zone 8
# is (-112.5°, -90°] (right-rear) and zone 15 is (90°, 112.5°] (left-rear).
N_ZONES = 16
ZONE_START_DEG = 90.0
ZONE_WIDTH_DEG = 360.0 / N_ZONES


def zone_bounds_deg(k: int) -> tuple[float, float]:
    """Half-open interval (low, high] of robot-frame angles, in degrees, of lidar zone k."""
    if not 0 <= k < N_ZONES:
        raise ValueError(f"zone index must be in [0, {N_ZONES}), got {k}")
    high = ZONE_START_DEG - ZONE_WIDTH_DEG * k
    return high - ZONE_WIDTH_DEG, high


def wrap_angle(a: float) -> float:
    """Wraps an angle in radians to [-π, π)."""
    return (a + math.pi) % (2.0 * math.pi) - math.pi
