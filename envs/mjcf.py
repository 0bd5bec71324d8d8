"""MJCF builder: robot + range sensors + arena boxes → a standalone MuJoCo XML string.

The model is what MJX needs to compute the paper's proximity readings (§5.1, §5.2) and
nothing more (docs/architecture.md, "Environment"):

* a round Pioneer-3DX-like robot: a sphere of radius r (MJX has no cylinder-box
  collisions and its rays ignore cylinders) on planar joints slide x, slide y, hinge z;
  its centre is at height r, so ``qpos = (x, y, θ)`` is the pose in the world frame;
* ``rangefinder`` sensors on sites: the 16-sonar ring of ``contract/spec.py`` (sites on the
  body circle at ``SONAR_MOUNTS_DEG`` looking along ``SONAR_DIRECTIONS_DEG``) or, for the
  physical arena, a lidar of n beams from the robot centre. A rangefinder looks along
  its site's +z axis, so each site's z axis is set horizontal;
* walls and obstacles as boxes ``BOX_HEIGHT`` tall (ray-visible), a floor plane that the
  horizontal rays never hit (MuJoCo only hits a plane from its front side), and a
  material (MJX's ray code needs one). The goal is not in the model: it is state.
* gravity off and contacts off: the robot is moved kinematically and collisions are
  decided geometrically (``geometry.py``) and by the sensor rule.

The XML loads in plain MuJoCo (``mujoco.MjModel.from_xml_string``) and in the viewer.
``MjxSensors`` puts it on MJX and reads the sensors at a pose: ``qpos`` ← pose, then
``mjx.kinematics`` and ``mjx.sensor_pos`` (nothing else of MuJoCo's pipeline is needed).
"""

from __future__ import annotations

import contextlib
import dataclasses
import io
import math
from typing import TYPE_CHECKING

import jax
import jax.numpy as jnp
import mujoco
import numpy as np

# mujoco-mjx 3.17 prints "Failed to import warp" on import when the optional NVIDIA Warp
# backend is absent; we use the JAX backend only, so keep that line off the user's screen.
with contextlib.redirect_stdout(io.StringIO()):
    from mujoco import mjx

from advisor_jax.contract import spec
from advisor_jax.contract.zones import reduce_to_zones
from envs.layouts import BOX_HEIGHT, procedural_active

if TYPE_CHECKING:
    from envs.motion import DriveParams


@dataclasses.dataclass(frozen=True)
class SensorRig:
    """Where the rangefinders sit and look (robot frame, degrees CCW, 0 = forward)."""

    kind: str  # "sonar" | "lidar"
    directions_deg: tuple[float, ...]
    mounts_deg: tuple[float, ...]  # angle of the site on a circle of radius mount_radius
    mount_radius: float  # m; 0 puts every site at the robot centre
    cutoff: float  # m; MuJoCo clips readings to it, "no hit" stays -1

    @property
    def n(self) -> int:
        return len(self.directions_deg)


def sonar_rig(robot_radius: float, max_range: float) -> SensorRig:
    """The P3DX sonar ring of ``spec``: sites on the body circle, free distance readings."""
    return SensorRig(
        kind="sonar",
        directions_deg=tuple(spec.SONAR_DIRECTIONS_DEG),
        mounts_deg=tuple(spec.SONAR_MOUNTS_DEG),
        mount_radius=robot_radius,
        cutoff=max_range,
    )


def lidar_beam_angles_deg(n_beams: int) -> np.ndarray:
    """Beam directions of an n-beam lidar, evenly spread over 360°.

    Offset by a quarter step from 0°: the 16 zone boundaries lie at multiples of 22.5°,
    which for 200 beams (1.8° steps) fall both on whole and on half steps, so a half-step
    offset would put every other boundary on a beam. A quarter step keeps every beam at
    least 0.45° away from every boundary.
    """
    step = 360.0 / n_beams
    return (np.arange(n_beams) + 0.25) * step


def lidar_rig(n_beams: int, robot_radius: float, max_range: float) -> SensorRig:
    """A lidar at the robot centre; cutoff max_range + r so max_range of free distance reads."""
    angles = tuple(float(a) for a in lidar_beam_angles_deg(n_beams))
    return SensorRig(
        kind="lidar",
        directions_deg=angles,
        mounts_deg=angles,
        mount_radius=0.0,
        cutoff=max_range + robot_radius,
    )


def _f(x: float) -> str:
    return f"{float(x):.6g}"


def _vec(*xs: float) -> str:
    return " ".join(_f(x) for x in xs)


def box_geom_z(boxes: np.ndarray) -> np.ndarray:
    """Height of each box centre; parked procedural slots are sunk below the floor."""
    return np.where(procedural_active(np.asarray(boxes)), BOX_HEIGHT / 2.0, -BOX_HEIGHT)


def arena_xml(
    name: str,
    boxes: np.ndarray,
    bounds: tuple[float, float, float, float],
    rig: SensorRig,
    *,
    robot_radius: float,
    dt: float,
    n_walls: int = 4,
    drive: DriveParams | None = None,
) -> str:
    """Standalone MJCF of one arena.

    Args:
      name: model name.
      boxes: [n, 5] (cx, cy, hx, hy, angle), the first ``n_walls`` rows are walls.
      bounds: free floor (xmin, xmax, ymin, ymax), for the floor plane's extent.
      rig: the range sensors.
      robot_radius: m.
      dt: control period, written as the model timestep (``drive``: dt / substeps).
      n_walls: leading rows drawn in the wall colour.
      drive: the ``mjx`` motion model's robot (mass, inertia, wheel sites and actuators,
        ``drive_parts``); None (the ``kinematic`` model) writes today's model unchanged.

    Box geoms are named ``box0`` … in row order; sensors ``range0`` … in rig order.
    """
    boxes = np.asarray(boxes, np.float64)
    if boxes.ndim != 2 or boxes.shape[1] != 5:
        raise ValueError(f"boxes must have shape [n, 5], got {boxes.shape}")
    if not np.all(np.isfinite(boxes)):
        raise ValueError("boxes contain non-finite values")
    zs = box_geom_z(boxes)
    floor_half = (
        (bounds[1] - bounds[0]) / 2.0 + 0.5,
        (bounds[3] - bounds[2]) / 2.0 + 0.5,
    )
    floor_center = ((bounds[0] + bounds[1]) / 2.0, (bounds[2] + bounds[3]) / 2.0)

    geoms = []
    for i, (cx, cy, hx, hy, angle) in enumerate(boxes):
        material = "wall" if i < n_walls else "obstacle"
        geoms.append(
            f'    <geom name="box{i}" type="box" pos="{_vec(cx, cy, zs[i])}" '
            f'size="{_vec(hx, hy, BOX_HEIGHT / 2.0)}" euler="0 0 {_f(angle)}" '
            f'material="{material}"/>'
        )

    sites, sensors = [], []
    for i, (direction, mount) in enumerate(zip(rig.directions_deg, rig.mounts_deg, strict=True)):
        a, m = math.radians(direction), math.radians(mount)
        pos = (rig.mount_radius * math.cos(m), rig.mount_radius * math.sin(m), 0.0)
        sites.append(
            f'      <site name="range{i}" pos="{_vec(*pos)}" '
            f'zaxis="{_vec(math.cos(a), math.sin(a), 0.0)}" size="0.01" rgba="1 1 0 1"/>'
        )
        sensors.append(
            f'    <rangefinder name="range{i}" site="range{i}" cutoff="{_f(rig.cutoff)}"/>'
        )

    r = robot_radius
    parts = drive_parts(drive, dt) if drive is not None else DriveParts()
    return "\n".join(
        [
            f'<mujoco model="{name}">',
            '  <compiler angle="radian"/>',
            parts.option or _option(dt),
            '    <flag contact="disable"/>',
            "  </option>",
            "  <asset>",
            '    <material name="floor" rgba="0.85 0.85 0.85 1"/>',
            '    <material name="wall" rgba="0.35 0.35 0.4 1"/>',
            '    <material name="obstacle" rgba="0.75 0.45 0.2 1"/>',
            '    <material name="robot" rgba="0.8 0.1 0.1 1"/>',
            "  </asset>",
            "  <worldbody>",
            '    <light pos="0 0 6" dir="0 0 -1" directional="true"/>',
            f'    <geom name="floor" type="plane" pos="{_vec(*floor_center, 0.0)}" '
            f'size="{_vec(*floor_half, 0.1)}" material="floor"/>',
            *geoms,
            f'    <body name="robot" pos="0 0 {_f(r)}">',
            '      <joint name="x" type="slide" axis="1 0 0"/>',
            '      <joint name="y" type="slide" axis="0 1 0"/>',
            '      <joint name="yaw" type="hinge" axis="0 0 1"/>',
            *parts.inertial,
            f'      <geom name="robot" type="sphere" size="{_f(r)}" material="robot" mass="9"/>',
            f'      <site name="front" pos="{_vec(r, 0.0, 0.1)}" size="0.03" rgba="0 0 1 1"/>',
            *parts.sites,
            *sites,
            "    </body>",
            "  </worldbody>",
            *parts.actuators,
            "  <sensor>",
            *sensors,
            "  </sensor>",
            "</mujoco>",
            "",
        ]
    )


def _option(timestep: float, integrator: str = "") -> str:
    extra = f' integrator="{integrator}"' if integrator else ""
    return f'  <option timestep="{_f(timestep)}" gravity="0 0 0"{extra}>'


@dataclasses.dataclass(frozen=True)
class DriveParts:
    """MJCF lines of the ``mjx`` motion model's robot (empty: the kinematic robot)."""

    option: str = ""  # <option ...> opening tag: physics step and integrator
    inertial: tuple[str, ...] = ()  # lines inside the robot body
    sites: tuple[str, ...] = ()  # the wheels' ground contact points and the centre
    actuators: tuple[str, ...] = ()  # the <actuator> section


def drive_parts(drive: DriveParams, dt: float) -> DriveParts:
    """The robot's mass, inertia, wheel sites and actuators (``envs/motion.py``).

    Two velocity servos act along the heading at the wheels' ground contact points
    (0, ±b/2): force k_v (ctrl − rim speed), ctrl clamped to ±rim_speed_max and force
    to ±wheel_force_max. A third servo at the centre, across the heading, with target 0
    and gain m / h removes any side slip in one physics step h = dt / substeps. The
    centre of mass is at the body origin, so the mass matrix is diag(m, m, I).
    """
    h = dt / drive.substeps
    b2, kv = 0.5 * drive.axle_track, drive.servo_gain()
    rim, force = drive.rim_speed_max, drive.wheel_force_max
    side_ixx = 0.6 * drive.yaw_inertia  # any value: x and y rotations are not joints
    wheel = (
        f'gear="1 0 0 0 0 0" kv="{_f(kv)}" ctrllimited="true" '
        f'ctrlrange="{_vec(-rim, rim)}" forcelimited="true" forcerange="{_vec(-force, force)}"'
    )
    return DriveParts(
        option=_option(h, "Euler"),
        inertial=(
            f'      <inertial pos="0 0 0" mass="{_f(drive.mass)}" '
            f'diaginertia="{_vec(side_ixx, side_ixx, drive.yaw_inertia)}"/>',
        ),
        sites=(
            f'      <site name="wheel_left" pos="{_vec(0.0, b2, 0.0)}" size="0.02"/>',
            f'      <site name="wheel_right" pos="{_vec(0.0, -b2, 0.0)}" size="0.02"/>',
            '      <site name="centre" pos="0 0 0" size="0.02"/>',
        ),
        actuators=(
            "  <actuator>",
            f'    <velocity name="wheel_left" site="wheel_left" {wheel}/>',
            f'    <velocity name="wheel_right" site="wheel_right" {wheel}/>',
            f'    <velocity name="side_grip" site="centre" gear="0 1 0 0 0 0" '
            f'kv="{_f(drive.mass / h)}"/>',
            "  </actuator>",
        ),
    )


def drive_xml(drive: DriveParams, dt: float, robot_radius: float) -> str:
    """MJCF of the robot alone (no boxes, no sensors, contacts off): what ``mjx.step``
    advances under the ``mjx`` motion model (``motion.MjxDrive``)."""
    parts = drive_parts(drive, dt)
    return "\n".join(
        [
            '<mujoco model="drive">',
            '  <compiler angle="radian"/>',
            parts.option,
            '    <flag contact="disable"/>',
            "  </option>",
            "  <worldbody>",
            f'    <body name="robot" pos="0 0 {_f(robot_radius)}">',
            '      <joint name="x" type="slide" axis="1 0 0"/>',
            '      <joint name="y" type="slide" axis="0 1 0"/>',
            '      <joint name="yaw" type="hinge" axis="0 0 1"/>',
            *parts.inertial,
            *parts.sites,
            "    </body>",
            "  </worldbody>",
            *parts.actuators,
            "</mujoco>",
            "",
        ]
    )


@jax.jit
def _sensor_pass(m: mjx.Model, d: mjx.Data) -> jax.Array:
    """MJX's kinematics and sensor pass: ``d``'s sensordata. One jitted function, so that
    JAX traces MJX's rays once per model and shape, not once per program that holds them
    (a trace takes about a second on a CPU; XLA inlines the call)."""
    # MJX maps rays into geom frames with small matmuls; JAX's default precision runs
    # them in TF32 on recent GPUs (errors of 0.4 mm, 7 mm for the lidar): use full fp32.
    with jax.default_matmul_precision("highest"):
        return mjx.sensor_pos(m, mjx.kinematics(m, d)).sensordata


class MjxSensors:
    """An arena's model on MJX and its sensor pass, from the pose [3] = qpos.

    With ``per_env_boxes`` (procedural arena) each call takes the env's boxes [n, 5] and
    writes them into ``geom_pos/size/quat`` of the box geoms: under vmap those fields, and
    only those, are batched. Otherwise the model is a closure constant.
    """

    def __init__(
        self,
        xml: str,
        rig: SensorRig,
        n_boxes: int,
        *,
        per_env_boxes: bool,
        max_range: float,
        robot_radius: float,
    ):
        self.mj_model = mujoco.MjModel.from_xml_string(xml)
        # This process's own device: in a multi-host job jax.devices()[0] belongs to
        # process 0, and the constants of the compiled step must live where it runs.
        device = jax.local_devices()[0]
        self.model = mjx.put_model(self.mj_model, device=device, impl="jax")
        self.data = mjx.make_data(self.model, device=device, impl="jax")
        self.rig, self.per_env_boxes = rig, per_env_boxes
        self.max_range, self.robot_radius = max_range, robot_radius
        obj = mujoco.mjtObj.mjOBJ_GEOM
        self.box_geoms = np.array(
            [mujoco.mj_name2id(self.mj_model, obj, f"box{i}") for i in range(n_boxes)]
        )
        self.beam_angles = jnp.asarray(np.radians(rig.directions_deg), jnp.float32)

    def model_for(self, boxes: jax.Array | None) -> mjx.Model:
        """The MJX model, with ``boxes`` [n, 5] written into the box geoms if per-env."""
        m = self.model
        if not self.per_env_boxes or boxes is None:
            return m
        ids = self.box_geoms
        half_z = jnp.full((boxes.shape[0], 1), BOX_HEIGHT / 2.0)
        z = jnp.where(procedural_active(boxes), half_z[:, 0], -BOX_HEIGHT)  # parked: sunk
        pos = m.geom_pos.at[ids].set(jnp.concatenate([boxes[:, :2], z[:, None]], axis=-1))
        size = m.geom_size.at[ids].set(jnp.concatenate([boxes[:, 2:4], half_z], axis=-1))
        half = boxes[:, 4] / 2.0
        zero = jnp.zeros_like(half)
        quat = m.geom_quat.at[ids].set(jnp.stack([jnp.cos(half), zero, zero, jnp.sin(half)], -1))
        return m.replace(geom_pos=pos, geom_size=size, geom_quat=quat)

    def readings(self, pose: jax.Array, boxes: jax.Array | None = None) -> jax.Array:
        """Raw rangefinder readings [n_rays] at ``pose`` (m; −1 = no hit within cutoff)."""
        m = self.model_for(boxes)
        return _sensor_pass(m, self.data.replace(qpos=pose.astype(self.data.qpos.dtype)))

    def proximity(self, pose: jax.Array, boxes: jax.Array | None = None) -> jax.Array:
        """The 16 proximity readings P (m): sonar readings with −1 → max_range, or the
        lidar reduced to 16 zones of free distance (``contract.zones.reduce_to_zones``)."""
        raw = self.readings(pose, boxes).astype(jnp.float32)
        if self.rig.kind == "lidar":
            return reduce_to_zones(
                self.beam_angles,
                raw,
                max_range=self.max_range,
                range_offset=self.robot_radius,
                xp=jnp,
            )
        return jnp.where(raw < 0.0, self.max_range, jnp.minimum(raw, self.max_range))
