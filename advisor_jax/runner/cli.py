"""``advisor-jax-car``: drive the physical car with an exported policy, or replay a log.

    advisor-jax-car POLICY_DIR --goal X Y --drive ackermann --wheelbase 0.26 --max-steer 25 \\
        [--rate HZ] [--lidar-port /dev/ttyUSB0] [--pose-udp 0.0.0.0:5005] [--log FILE] \\
        [--limits FILE] [--max-speed M/S] [--max-yaw-rate RAD/S] [--verify-key KEYFILE] \\
        [--dry-run | --motor package.module:factory]
    advisor-jax-car POLICY_DIR --sim [--seed S] [--goal X Y] [--log FILE]   # no car
    advisor-jax-car --replay LOG [POLICY_DIR]

Driving: verifies the export (``policy.load_policy``; its signature too with
``--verify-key``), refuses a policy that would command more than the car's own limits
(``limits.py``: built-in spec, ``--limits FILE``, flags; never the policy directory) and
prints them, checks the goal against the arena bounds, creates the log (a new file: never
over an existing one), opens the lidar and the pose socket, and runs the watchdog loop
(``loop.py``) until the goal, a collision, ``--max-cycles`` or Ctrl-C / SIGTERM; motors are
stopped on every exit path, with further signals ignored until they are. ``--dry-run``
prints the commands instead of sending them. Replay re-feeds a log's
inputs through the policy and exits 1 if any decision differs. ``--sim`` runs the same
loop against the simulated physical arena (``advisor_jax/cli/car.py`` supplies the
simulator, which needs JAX; this module does not import it). Errors print one line
(``advisor-jax-car: error: ...``) and exit 2. argparse only: no tyro on the car.

OpenBLAS is limited to one thread (unless OPENBLAS_NUM_THREADS is already set) before numpy
is imported: for the actor's small matrix-vector products, waking BLAS worker threads costs
more than it saves and adds latency jitter (experiments/bench_runner.py).
"""

from __future__ import annotations

import os

os.environ.setdefault("OPENBLAS_NUM_THREADS", "1")  # must precede the first numpy import

import argparse  # noqa: E402
import math  # noqa: E402
import signal  # noqa: E402
import sys  # noqa: E402
from collections.abc import Callable, Sequence  # noqa: E402

from advisor_jax.runner import cyclelog, hardware  # noqa: E402
from advisor_jax.runner.cyclelog import log_header  # noqa: E402
from advisor_jax.runner.drive import AckermannDrive, DiffDrive  # noqa: E402
from advisor_jax.runner.errors import RunnerError  # noqa: E402
from advisor_jax.runner.limits import check_policy, limits_from_options  # noqa: E402
from advisor_jax.runner.loop import (  # noqa: E402
    Controller,
    LoopConfig,
    run_loop,
    signals_ignored,
)
from advisor_jax.runner.observation import ObservationBuilder, ObservationConfig  # noqa: E402
from advisor_jax.runner.options import PROG, build_parser  # noqa: E402
from advisor_jax.runner.policy import load_policy  # noqa: E402
from advisor_jax.runner.replay import replay  # noqa: E402


def _drive_from_args(args: argparse.Namespace):
    if args.drive == "diff":
        if args.track_width is None:
            raise ValueError("--drive diff needs --track-width M")
        return DiffDrive(args.track_width, args.max_wheel_speed)
    if args.drive == "ackermann":
        if args.wheelbase is None or args.max_steer is None:
            raise ValueError("--drive ackermann needs --wheelbase M and --max-steer DEG")
        return AckermannDrive(args.wheelbase, math.radians(args.max_steer))
    raise ValueError("choose --drive diff or --drive ackermann")


def _host_port(text: str) -> tuple[str, int]:
    host, _, port = text.rpartition(":")
    if not host or not port.isdigit():
        raise ValueError(f"--pose-udp {text!r} must look like HOST:PORT, e.g. 0.0.0.0:5005")
    return host, int(port)


def _default(value, env: dict, key: str, fallback):
    if value is not None:
        return value
    found = env.get(key)
    return float(found) if isinstance(found, int | float) else fallback


def _raise_interrupt(signum, frame):
    raise KeyboardInterrupt(f"signal {signum}")


def _shutdown(motor, *sources) -> None:
    """Stop the motors first, then release everything; report but survive close errors."""
    for what, action in [("motor stop", motor.stop)] + [
        (type(c).__name__, c.close) for c in (*sources, motor) if c is not None
    ]:
        try:
            action()
        except Exception as e:
            print(f"{PROG}: warning: {what} failed: {e}", file=sys.stderr)


def drive(args: argparse.Namespace, simulator: Callable | None = None) -> int:
    """Drives the car, or with ``simulator`` (``--sim``; ``advisor_jax.cli.car``) the same
    loop against a simulated car: ``simulator(args, policy)`` returns an object that is
    the lidar, the tracker, the motors and the clock (``evaluation.sim_car.SimulatedCar``)."""
    if args.sim and simulator is None:
        raise ValueError(
            "--sim needs advisor-jax's simulator (JAX, MuJoCo): run advisor-jax-car from a "
            "full install (pip install advisor-jax), not the car's numpy-only one"
        )
    if args.policy_dir is None or (args.goal is None and not args.sim):
        raise ValueError("driving needs POLICY_DIR and --goal X Y")
    if args.sim and (args.motor or args.dry_run):
        raise ValueError("--sim drives the simulated car: leave out --motor and --dry-run")
    drive_model = _drive_from_args(args) if args.drive or not args.sim else None
    host, port = _host_port(args.pose_udp)
    if args.rate is not None and not (math.isfinite(args.rate) and args.rate > 0):
        raise ValueError(f"--rate {args.rate:g} Hz: the control rate must be a positive number")
    limits, key = limits_from_options(args.limits, args.max_speed, args.max_yaw_rate,
                                      args.verify_key)  # fmt: skip
    policy = load_policy(args.policy_dir, verify_key=key)
    check_policy(os.path.join(args.policy_dir, "policy.json"), policy.v_max, policy.omega_max,
                 limits)  # fmt: skip
    car = simulator(args, policy) if args.sim else None
    goal = tuple(args.goal) if args.goal is not None else car.goal
    if car is not None:
        drive_model = car.drive = drive_model or car.drive  # the sim inverts the same drive
    controller, rate = _controller(args, policy, limits, goal, drive_model)
    if car is not None:
        motor = car
    elif args.dry_run:
        motor = hardware.PrintMotorDriver()
    elif args.motor:
        motor = hardware.load_motor_driver(args.motor)
    else:
        raise ValueError("no motor driver: pass --motor MODULE:FACTORY, or --dry-run")
    if args.log is not None and os.path.lexists(args.log):  # before any hardware is opened
        raise FileExistsError(f"{args.log} exists already; it is never overwritten: choose "
                              "another --log")  # fmt: skip
    log = log_path = scans = poses = None
    previous_handler = signal.signal(signal.SIGTERM, _raise_interrupt)  # systemd/kill → stop
    try:
        motor.stop()
        if car is None:
            scans = hardware.RplidarScanSource(args.lidar_port, baudrate=args.lidar_baud)
            poses = hardware.UdpPoseSource(host, port)
            timing = {}
        else:
            scans, poses, timing = car.scans, car.poses, {"clock": car.clock, "sleep": car.sleep}
        log = cyclelog.new_log(args.log, PROG)  # a new file, never over an existing one
        log_path = log.path
        log.write(log_header(controller, policy, argv=sys.argv))
        where = "the simulated car" if car is not None else ""
        print(
            f"{PROG}: driving {where + ' ' if where else ''}to ({goal[0]:g}, {goal[1]:g}) at "
            f"{rate:g} Hz within the {limits.describe()}; log {log_path}; Ctrl-C stops",
            file=sys.stderr,
        )
        summary = run_loop(controller, scans, poses, motor, log=log, **timing)
    except KeyboardInterrupt:
        with signals_ignored():
            print(f"{PROG}: interrupted; motors stopped; log {log_path}", file=sys.stderr)
        return 130
    finally:
        with signals_ignored():
            signal.signal(signal.SIGTERM, previous_handler)
            _shutdown(motor, *((scans, poses) if car is None else ()))
            if log is not None:
                log.close()
    stops = ", ".join(f"{k} x{v}" for k, v in summary.stops.items()) or "none"
    print(
        f"{PROG}: ended ({summary.end}) after {summary.cycles} cycles; stops: {stops}; "
        f"overruns: {summary.overruns}; log {log_path}",
        file=sys.stderr,
    )
    return 0


def _controller(args, policy, limits, goal, drive_model) -> tuple[Controller, float]:
    """The watchdog controller the options describe, and its control rate."""
    obs_cfg = ObservationConfig(
        max_range=policy.max_range,
        range_offset=policy.range_offset if args.range_offset is None else args.range_offset,
        mount_yaw_deg=args.lidar_yaw,
        min_quality=args.min_quality,
        min_range=args.min_range,
        min_valid_points=args.min_valid,
        max_speed=args.max_pose_speed,
        bounds=policy.bounds,
    )
    if args.range_offset is not None and args.range_offset != policy.range_offset:
        print(
            f"{PROG}: warning: --range-offset {args.range_offset:g} m differs from the "
            f"{policy.range_offset:g} m the policy was trained with: every obstacle reads "
            f"{abs(args.range_offset - policy.range_offset):g} m "
            f"{'nearer' if args.range_offset > policy.range_offset else 'farther'} than in "
            "training (correct only if that is this car's lidar-to-body-edge distance)",
            file=sys.stderr,
        )
    builder = ObservationBuilder(obs_cfg, goal)
    collision = _default(args.collision_distance, policy.env, "T_c", None)
    if args.collision_distance is None and collision is not None and not collision >= 0:
        raise ValueError(  # only the operator may turn the collision stop off, never a file
            f"{args.policy_dir}: env.T_c = {collision:g} in policy.json would turn the "
            "collision stop off; give --collision-distance to choose it on the car's side"
        )
    rate = args.rate if args.rate is not None else 1.0 / policy.dt
    max_cycles = args.max_cycles
    if args.sim and max_cycles is None:  # a simulated episode ends at h_max, as in training
        max_cycles = int(policy.env.get("h_max") or 0) or None
    loop_cfg = LoopConfig(
        rate_hz=rate,
        max_scan_age=args.max_scan_age,
        max_pose_age=args.max_pose_age,
        goal_tolerance=_default(args.goal_tolerance, policy.env, "T_g", 0.15),
        collision_distance=None if collision is None or collision < 0 else collision,
        max_cycles=max_cycles,
        max_speed=limits.max_speed,
        max_yaw_rate=limits.max_yaw_rate,
        warm_up=args.warm_up,
    )
    controller = Controller(policy, builder, drive_model, loop_cfg)
    if abs(rate * policy.dt - 1.0) > 0.01:
        print(
            f"{PROG}: warning: rate {rate:g} Hz differs from the training rate "
            f"{1 / policy.dt:g} Hz; the velocity inputs will not match",
            file=sys.stderr,
        )
    return controller, rate


def replay_command(args: argparse.Namespace) -> int:
    _, key = limits_from_options(args.limits, None, None, args.verify_key)
    report = replay(args.replay, args.policy_dir, tolerance=args.replay_tolerance, verify_key=key)
    for line in report.mismatches:
        print(f"  mismatch: {line}")
    if not report.ok:
        print(
            f"{PROG}: error: replay differs from the log in {report.mismatched} of "
            f"{report.replayed} cycles (max action difference {report.max_action_diff:.3g})",
            file=sys.stderr,
        )
        return 1
    print(
        f"{PROG}: replayed {report.replayed} of {report.cycles} cycles ({report.driving} "
        "driving): every state, observation, action and command reproduced "
        f"{'exactly' if args.replay_tolerance == 0 else 'within tolerance'}"
    )
    return 0


def main(argv: Sequence[str] | None = None, simulator: Callable | None = None) -> int:
    """Entry point of the car's runner; ``simulator`` enables ``--sim`` (``cli/car.py``)."""
    args = build_parser().parse_args(argv)
    try:
        return replay_command(args) if args.replay else drive(args, simulator)
    except (RunnerError, ValueError, OSError) as e:
        print(f"{PROG}: error: {e}", file=sys.stderr)
        return 2
    except Exception as e:  # the last line of defence: still one line, never a traceback
        print(f"{PROG}: error: unexpected {type(e).__name__}: {e}", file=sys.stderr)
        return 2


if __name__ == "__main__":
    sys.exit(main())
