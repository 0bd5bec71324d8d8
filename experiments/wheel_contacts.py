"""Why the ``mjx`` motion model drives a planar body instead of wheels rolling on a floor.

The obvious MJX model of a differential-drive robot is a free-floating chassis under
gravity with two wheels on hinge joints, velocity-servoed, rolling on the floor through
contacts, and a frictionless caster. This script steps that model with MJX at several
physics steps h and compares it with the model the envs use (``envs/motion.py``: a planar
body, forces at the wheel contact points, ``substeps`` = 5), measuring for each:

* whether a control period of dt = 0.05 s of full throttle from rest, repeated for 2 s,
  stays physical: the chassis neither sinks nor flies (|z - z0| < 1 cm), no NaN;
* the speed reached after 2 s (target 1 m/s; the planar model's torque limit gives the
  same 1.37 m/s² to both, so both should reach it);
* the cost of one control period for ``--envs`` vmapped robots (best of ``--repeats``).

    python experiments/wheel_contacts.py --date 2026-11-26   # ~5 min on a 2-core CPU

Writes ``<out>.md`` and ``<out>.json`` (default ``results/wheel_contacts``).
"""

from __future__ import annotations

import dataclasses
import pathlib
import sys

import jax
import jax.numpy as jnp
import mujoco
import numpy as np
import tyro

import envs
from advisor_jax.bench import measure, writing
from advisor_jax.fileio import atomic_write_json
from envs.mjcf import mjx

DT, SECONDS = 0.05, 2.0


@dataclasses.dataclass(frozen=True)
class Args:
    steps: tuple[float, ...] = (0.05, 0.01, 0.005, 0.002)
    """Physics steps h (s) of the wheeled model; dt / h substeps per control period."""
    envs: int = 256
    """Robots stepped in parallel for the timing."""
    repeats: int = 3
    """Timed calls per model; the best is reported."""
    out: str = "results/wheel_contacts"
    """Output path without extension (.md and .json)."""
    date: str = ""
    """Date to record (default: today)."""


def wheeled_xml(h: float, drive: envs.DriveParams) -> str:
    """A P3DX on wheels: chassis (free joint), two sphere wheels on hinges with the drive's
    radius, torque and speed limits, a frictionless caster; gravity and contacts on."""
    r, b2, m = drive.wheel_radius, drive.axle_track / 2, drive.mass
    wheel_mass, caster = 1.0, 0.03
    servo = (
        f'kv="{drive.servo_gain() * r * r:.6g}" ctrllimited="true" '
        f'ctrlrange="{-drive.wheel_speed_max} {drive.wheel_speed_max}" forcelimited="true" '
        f'forcerange="{-drive.wheel_torque_max} {drive.wheel_torque_max}"'
    )
    wheels = "".join(
        f'<body name="{side}" pos="0 {y} 0"><joint name="{side}" type="hinge" axis="0 1 0"/>'
        f'<geom type="sphere" size="{r}" mass="{wheel_mass}" friction="1 0.005 0.0001"/></body>'
        for side, y in (("left", b2), ("right", -b2))
    )
    return f"""<mujoco model="wheeled">
  <option timestep="{h}" integrator="implicitfast"/>
  <worldbody>
    <geom name="floor" type="plane" size="5 5 0.1"/>
    <body name="chassis" pos="0 0 {r}">
      <freejoint/>
      <geom type="box" size="0.2 0.15 0.05" pos="0 0 0.05" mass="{m - 2 * wheel_mass}"/>
      <geom type="sphere" size="{caster}" pos="-0.17 0 {caster - r}" condim="1" mass="0.01"/>
      {wheels}
    </body>
  </worldbody>
  <actuator>
    <velocity joint="left" {servo}/>
    <velocity joint="right" {servo}/>
  </actuator>
</mujoco>
"""


def wheeled_run(h: float, drive: envs.DriveParams, n: int, repeats: int) -> dict:
    """Full throttle from rest for 2 s: physical? final speed; seconds per control period."""
    model = mjx.put_model(mujoco.MjModel.from_xml_string(wheeled_xml(h, drive)), impl="jax")
    data = mjx.make_data(model, impl="jax")
    substeps = max(1, round(DT / h))
    target = 1.0 / drive.wheel_radius  # rad/s for 1 m/s
    data = data.replace(ctrl=jnp.full(2, target, data.ctrl.dtype))
    z0 = float(data.qpos[2])

    def period(d, _):
        d = jax.lax.fori_loop(0, substeps, lambda _, d: mjx.step(model, d), d)
        return d, (d.qpos[2], d.qvel[0])

    periods = round(SECONDS / DT)
    run = jax.jit(lambda d: jax.lax.scan(period, d, None, length=periods)[1])
    z, speed = (np.asarray(x) for x in run(data))
    batch = jax.tree_util.tree_map(lambda x: jnp.broadcast_to(x, (n, *x.shape)), data)
    one_period = jax.jit(jax.vmap(lambda d: period(d, None)[0]))
    _, best = measure.first_and_best(lambda: one_period(batch), repeats)
    finite = bool(np.all(np.isfinite(z)) and np.all(np.isfinite(speed)))
    drift = float(np.nanmax(np.abs(z - z0))) if finite else float("nan")
    return {
        "model": "wheels on a floor (contacts)",
        "h": h,
        "substeps": substeps,
        "physical": finite and drift < 0.01,
        "z_drift_m": drift,
        "speed_after_2s": float(speed[-1]) if finite else float("nan"),
        "seconds_per_period": best,
    }


def planar_run(n: int, repeats: int) -> dict:
    """The envs' model (``envs/motion.py``) on the same test."""
    env = envs.make_env("training", motion="mjx")
    drive = env.drive
    pose, qvel = jnp.zeros(3), jnp.zeros(3)

    def period(carry, _):
        pose, _, qvel = drive.move(*carry, jnp.float32(1.0), jnp.float32(0.0))
        return (pose, qvel), qvel[0]

    speed = np.asarray(jax.jit(lambda c: jax.lax.scan(period, c, None, length=40)[1])((pose, qvel)))
    move = jax.jit(jax.vmap(lambda p, q: drive.move(p, q, jnp.float32(1.0), jnp.float32(0.0))))
    poses, qvels = jnp.zeros((n, 3)), jnp.zeros((n, 3))
    _, best = measure.first_and_best(lambda: move(poses, qvels), repeats)
    return {
        "model": "planar body (envs, motion=mjx)",
        "h": DT / drive.params.substeps,
        "substeps": drive.params.substeps,
        "physical": bool(np.all(np.isfinite(speed))),
        "z_drift_m": 0.0,
        "speed_after_2s": float(speed[-1]),
        "seconds_per_period": best,
    }


def main(args: Args) -> dict:
    where = measure.provenance()
    drive = envs.DriveParams()
    rows = [planar_run(args.envs, args.repeats)]
    for h in args.steps:
        rows.append(wheeled_run(h, drive, args.envs, args.repeats))
        print(rows[-1], flush=True)
    result = {
        **where,
        "date": args.date or where["date"],
        "command": writing.command_line("experiments/wheel_contacts.py", sys.argv[1:]),
        "envs": args.envs,
        "rows": rows,
    }
    out = pathlib.Path(args.out)
    atomic_write_json(out.with_suffix(".json"), result)
    base = rows[0]["seconds_per_period"]
    lines = [
        "# Wheels on a floor vs the planar body: the `mjx` motion model's form",
        "",
        f"- command: `{result['command']}`",
        f"- machine: {where['host']}, {where['cpu_count']} CPUs ({where['device']}), jax "
        f"{where['jax']}, date {result['date']}",
        f"- test: full throttle (1 m/s target) from rest for {SECONDS:g} s in control periods "
        f"of {DT} s; {args.envs} robots vmapped for the timing; the P3DX of `DriveParams()`",
        "",
        *writing.markdown_table(
            ("model", "physics step h (s)", "mjx.step per period", "stays on the floor",
             "max z drift (m)", "speed after 2 s (m/s)", "ms per period", "× planar"),
            [(r["model"], r["h"], r["substeps"], "yes" if r["physical"] else "no",
              r["z_drift_m"], r["speed_after_2s"], 1e3 * r["seconds_per_period"],
              r["seconds_per_period"] / base) for r in rows],
            formats=("", "g", "", "", ".2g", ".3f", ".2f", ".1f"),
        ),
    ]  # fmt: skip
    writing.write_markdown(out.with_suffix(".md"), lines)
    return result


if __name__ == "__main__":
    main(tyro.cli(Args))
