"""How a commanded (V, ω) moves the robot over one control step: the two motion models.

``EnvConfig.motion`` picks one for every arena (docs/architecture.md, "Environment";
the parameters and their sources: docs/arena_calibration.md):

* ``kinematic`` (the default): a unicycle. (V, ω) take effect at once; the pose moves
  along the arc with the heading taken at mid-step (exact speed, second-order arc)::

      θ_mid = θ + ω dt/2;   (x, y) += V dt (cos θ_mid, sin θ_mid);   θ += ω dt

* ``mjx``: a differential-drive body simulated by MJX (``mjx.step``), with the mass, yaw
  inertia, axle track, wheels and wheel limits of the paper's Pioneer 3-DX
  (``DriveParams``). The commanded (V, ω) become wheel-speed targets, which the wheels
  reach through torque-limited velocity servos, so speed and heading change at bounded
  rates (inertia, acceleration and turn-rate limits)::

      u_L, u_R = V ∓ ω b/2, each clamped to ±wheel_speed_max·r      (MuJoCo's ctrlrange)
      per substep h = dt / substeps (semi-implicit Euler, contacts and sensors off):
        F_wheel = clip(k_v (u − v_wheel), ±τ_max / r)   along the heading, at ±b/2
        F_side  = −(m / h) v_side                        no side slip (a dead-beat damper)
        (ẍ, ÿ, θ̈) = M⁻¹ (forces and yaw torque of the three)

  The body is planar (slide x, slide y, hinge yaw), so ``qpos`` is the pose and
  ``qvel`` = (ẋ, ẏ, θ̇) its world-frame velocity and yaw rate; the state carries ``qvel``.
  Wheel contact with the floor is not simulated (wheels rolling through MJX contacts are
  not physical at dt = 0.05 s and far costlier at short steps: results/wheel_contacts.md);
  the two wheels act where they touch the ground, and a rolling wheel's side grip is the
  dead-beat damper.

The speed never exceeds the commanded V ≤ v_max under either model: the wheel servos pull
the mean wheel speed monotonically towards V (k_v h ≤ the stable, overshoot-free bound)
and the side damper only removes speed, so ``reward.return_bounds`` holds for both (tested).
"""

from __future__ import annotations

import dataclasses
import math
from typing import Any

import jax
import jax.numpy as jnp
import mujoco

from advisor_jax.contract import spec
from envs.mjcf import mjx

MOTION_MODELS: tuple[str, ...] = spec.MOTION_MODELS  # ("kinematic", "mjx")
# ω_max (rad/s) of each model when not given: the paper leaves it open; calibrated on the
# advisor (results/advisor.md, docs/arena_calibration.md). 5 rad/s ≈ the P3DX's 300°/s.
DEFAULT_OMEGA_MAX: dict[str, float] = {"kinematic": 3.0, "mjx": 5.0}


@dataclasses.dataclass(frozen=True)
class DriveParams:
    """Physical parameters of the ``mjx`` motion model: a Pioneer 3-DX (sources and
    calibration: docs/arena_calibration.md)."""

    mass: float = 9.0  # kg, P3DX with one battery (spec sheet; Webots model 6.73 + 2 wheels)
    yaw_inertia: float = 0.26  # kg m², uniform 0.455 m × 0.381 m box of 9 kg
    axle_track: float = 0.33  # m, wheel separation b (Webots and V-REP P3DX models)
    wheel_radius: float = 0.0975  # m, r (195 mm wheels)
    wheel_speed_max: float = 12.3  # rad/s per wheel (Webots P3DX; 1.2 m/s at the rim)
    wheel_torque_max: float = 0.6  # N m per wheel at the axle (calibrated: 1.37 m/s²)
    servo_time_constant: float = 0.02  # s, wheel-speed servo below its torque limit
    substeps: int = 5  # mjx.step calls per control step (h = dt / substeps)

    def __post_init__(self):
        for f in dataclasses.fields(self):
            value = getattr(self, f.name)
            if f.name == "substeps":
                if isinstance(value, bool) or not isinstance(value, int) or value < 1:
                    raise ValueError(f"DriveParams.substeps must be an integer >= 1, got {value!r}")
                continue
            if isinstance(value, bool) or not isinstance(value, int | float):
                raise ValueError(f"DriveParams.{f.name} must be a number, got {value!r}")
            if not math.isfinite(value) or value <= 0:
                raise ValueError(f"DriveParams.{f.name} must be finite and positive, got {value}")

    # ---- derived limits (what the tests check the simulated robot against) -------------
    @property
    def wheel_force_max(self) -> float:
        """N, the most one wheel pushes along the heading: τ_max / r."""
        return self.wheel_torque_max / self.wheel_radius

    @property
    def rim_speed_max(self) -> float:
        """m/s, the fastest a wheel's contact point moves: ω_wheel,max · r."""
        return self.wheel_speed_max * self.wheel_radius

    @property
    def accel_max(self) -> float:
        """m/s², the largest change of forward speed: both wheels at full force, 2 F / m."""
        return 2.0 * self.wheel_force_max / self.mass

    @property
    def yaw_accel_max(self) -> float:
        """rad/s², the largest change of yaw rate: wheels in opposition, 2 F (b/2) / I."""
        return self.wheel_force_max * self.axle_track / self.yaw_inertia

    @property
    def turn_rate_max(self) -> float:
        """rad/s, the fastest spin on the spot: wheels at ∓ full rim speed, 2 v_rim / b."""
        return 2.0 * self.rim_speed_max / self.axle_track

    def servo_gain(self) -> float:
        """k_v (N per m/s) of a wheel servo: its faster mode (common: 2 k_v / m,
        differential: 2 k_v (b/2)² / I) relaxes with ``servo_time_constant``."""
        fastest = max(2.0 / self.mass, 0.5 * self.axle_track**2 / self.yaw_inertia)
        return 1.0 / (fastest * self.servo_time_constant)

    def check_step(self, dt: float) -> None:
        """ValueError unless explicit Euler at h = dt / substeps is stable and does not
        overshoot a wheel-speed target (h ≤ servo_time_constant)."""
        h = dt / self.substeps
        if h > self.servo_time_constant * (1.0 + 1e-9):
            raise ValueError(
                f"DriveParams: the physics step dt/substeps = {h:g} s exceeds "
                f"servo_time_constant = {self.servo_time_constant:g} s; raise substeps to "
                f"at least {math.ceil(dt / self.servo_time_constant)}"
            )


def parse_motion(setting: str) -> dict[str, Any]:
    """``EnvConfig`` fields of a motion setting: a model name, optionally with parameters,
    ``"kinematic"``, ``"mjx"`` or ``"mjx:wheel_torque_max=0.5,omega_max=4"``. Keys:
    ``omega_max`` (either model) and the ``DriveParams`` fields (``mjx`` only). ValueError
    with the fix for anything else. ``motion_setting`` is its inverse."""
    name, _, rest = str(setting).partition(":")
    if name not in MOTION_MODELS:
        raise ValueError(
            f"unknown motion model {name!r} in {setting!r}; choose one of "
            f"{', '.join(MOTION_MODELS)} (e.g. mjx or mjx:wheel_torque_max=0.5)"
        )
    fields = {f.name: f.type for f in dataclasses.fields(DriveParams)}
    allowed = ["omega_max"] + (list(fields) if name == "mjx" else [])
    out: dict[str, Any] = {"motion": name}
    drive: dict[str, Any] = {}
    for item in filter(None, rest.split(",")):
        key, eq, text = item.partition("=")
        key = key.strip()
        if not eq or key not in allowed:
            raise ValueError(
                f"bad motion parameter {item!r} in {setting!r}; write KEY=VALUE with KEY one "
                f"of {', '.join(allowed)}"
            )
        try:
            value = int(text) if fields.get(key) in (int, "int") else float(text)
        except ValueError:
            raise ValueError(f"motion parameter {key}={text!r} is not a number") from None
        (out if key == "omega_max" else drive)[key] = value
    if drive:
        out["drive"] = DriveParams(**drive)
    return out


def motion_setting(motion: str, drive: DriveParams, omega_max: float) -> str:
    """The canonical setting string of a config (``parse_motion``'s inverse): the model
    name, then every parameter that differs from its default, in declaration order."""
    changed = []
    if omega_max != DEFAULT_OMEGA_MAX[motion]:
        changed.append(f"omega_max={omega_max:g}")
    if motion == "mjx":
        default = DriveParams()
        for f in dataclasses.fields(DriveParams):
            value = getattr(drive, f.name)
            if value != getattr(default, f.name):
                changed.append(f"{f.name}={value:g}")
    return motion + (":" + ",".join(changed) if changed else "")


def unicycle_move(
    pose: jax.Array, v: jax.Array, w: jax.Array, dt: float
) -> tuple[jax.Array, jax.Array]:
    """The ``kinematic`` model: (pose [3], velocity [2]) after driving (v, w) for dt; the
    heading at mid-step, wrapped to [−π, π); velocity = displacement / dt (world frame)."""
    x, y, theta = pose[0], pose[1], pose[2]
    mid = theta + 0.5 * w * dt
    step_xy = v * dt * jnp.stack([jnp.cos(mid), jnp.sin(mid)])
    heading = jnp.mod(theta + w * dt + jnp.pi, 2.0 * jnp.pi) - jnp.pi
    return jnp.concatenate([jnp.stack([x, y]) + step_xy, heading[None]]), step_xy / dt


class MjxDrive:
    """The ``mjx`` model: the robot body of ``mjcf.drive_xml`` stepped by ``mjx.step``.

    ``move(pose, qvel, v, w)`` returns the pose and velocity after one control step. The
    model holds only the robot (no boxes, no sensors; contacts off), so it is the same for
    every arena and layout: a closure constant even in the procedural arena.
    """

    def __init__(self, xml: str, params: DriveParams, dt: float):
        params.check_step(dt)
        self.params = params
        self.mj_model = mujoco.MjModel.from_xml_string(xml)
        device = jax.local_devices()[0]
        self.model = mjx.put_model(self.mj_model, device=device, impl="jax")
        self.data = mjx.make_data(self.model, device=device, impl="jax")
        self.half_track = 0.5 * params.axle_track

    def wheel_targets(self, v: jax.Array, w: jax.Array) -> jax.Array:
        """ctrl [3]: rim-speed targets of the left and right wheel (m/s, clamped by the
        model's ctrlrange) and the side damper's target 0."""
        return jnp.stack([v - w * self.half_track, v + w * self.half_track, jnp.zeros_like(v)])

    def move(self, pose, qvel, v, w) -> tuple[jax.Array, jax.Array, jax.Array]:
        """(pose [3], velocity [2], qvel [3]) after one control step of the commanded
        (v m/s, w rad/s): the heading wrapped to [−π, π), the world-frame velocity
        averaged over the step (displacement / dt, as the car measures it from its tracked
        pose) and the body's velocity at the end of the step (the next step's start)."""
        dtype = self.data.qpos.dtype
        d = self.data.replace(
            qpos=pose.astype(dtype),
            qvel=qvel.astype(dtype),
            ctrl=self.wheel_targets(v, w).astype(dtype),
        )

        def substep(_, carry):
            d, summed = carry
            d = mjx.step(self.model, d)
            return d, summed + d.qvel[:2]  # semi-implicit Euler: x += h · qvel_new

        with jax.default_matmul_precision("highest"):
            d, summed = jax.lax.fori_loop(
                0, self.params.substeps, substep, (d, jnp.zeros(2, dtype))
            )
        heading = jnp.mod(d.qpos[2] + jnp.pi, 2.0 * jnp.pi) - jnp.pi
        new_pose = jnp.concatenate([d.qpos[:2], heading[None]]).astype(pose.dtype)
        velocity = (summed / self.params.substeps).astype(pose.dtype)
        return new_pose, velocity, d.qvel.astype(qvel.dtype)
