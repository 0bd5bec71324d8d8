"""``advisor-jax-car``: drive the physical car with an exported policy, or replay a log.

    advisor-jax-car POLICY_DIR --goal X Y --drive ackermann --wheelbase 0.26 --max-steer 25 \\
        [--rate HZ] [--lidar-port /dev/ttyUSB0] [--pose-udp 0.0.0.0:5005] [--log FILE] \\
        [--limits FILE] [--max-speed M/S] [--max-yaw-rate RAD/S] [--verify-key KEYFILE] \\
        [--dry-run | --motor package.module:factory]
    advisor-jax-car --replay LOG [POLICY_DIR]

Driving: verifies the export (``policy.load_policy``; its signature too with
``--verify-key``), refuses a policy that would command more than the car's own limits
(``limits.py``: built-in spec, ``--limits FILE``, flags; never the policy directory) and
prints them, checks the goal against the arena bounds, creates the log (a new file: never
over an existing one), opens the lidar and the pose socket, and runs the watchdog loop
(``loop.py``) until the goal, a collision, ``--max-cycles`` or Ctrl-C / SIGTERM; motors are
stopped on every exit path, with further signals ignored until they are. ``--dry-run``
prints the commands instead of sending them. Replay re-feeds a log's
inputs through the policy and exits 1 if any decision differs. Errors print one line
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
from collections.abc import Sequence  # noqa: E402

from advisor_jax.runner import cyclelog, hardware  # noqa: E402
from advisor_jax.runner.cyclelog import log_header  # noqa: E402
from advisor_jax.runner.drive import AckermannDrive, DiffDrive  # noqa: E402
from advisor_jax.runner.errors import RunnerError  # noqa: E402
from advisor_jax.runner.limits import CAR_SPEC, check_policy, limits_from_options  # noqa: E402
from advisor_jax.runner.loop import (  # noqa: E402
    Controller,
    LoopConfig,
    run_loop,
    signals_ignored,
)
from advisor_jax.runner.observation import ObservationBuilder, ObservationConfig  # noqa: E402
from advisor_jax.runner.policy import load_policy  # noqa: E402
from advisor_jax.runner.replay import replay  # noqa: E402

PROG = "advisor-jax-car"
EPILOG = """\
The tracker must send one UDP datagram per pose, a JSON object
  {"t": capture time s (its own clock), "x": m, "y": m, "theta": rad CCW from +x}
in the arena frame of policy.json (origin at the arena centre, x right, y up).
--dry-run uses the real lidar and tracker but prints motor commands instead of
sending them. Watchdog: the car stops on stale, missing or invalid data and on any
error, and drives again when fresh data arrive; the run ends at the goal
(d <= goal tolerance) or on a collision (min zone <= collision distance).
Defaults: rate 1/dt of policy.json, scan/pose max age 0.3 s, --min-valid 20,
--max-pose-speed 3 m/s, --pose-udp 0.0.0.0:5005, --lidar-port /dev/ttyUSB0.

examples:
  advisor-jax-car runs/export --goal 1.5 0.8 --drive ackermann --wheelbase 0.26 \\
      --max-steer 25 --motor mycar.motors:make_driver
  advisor-jax-car --replay advisor-jax-car-20261122-101500.jsonl
"""


def build_parser() -> argparse.ArgumentParser:
    p = argparse.ArgumentParser(
        prog=PROG,
        description="Drive the car with an exported policy (numpy only), or replay a log.",
        epilog=EPILOG,
        formatter_class=argparse.RawDescriptionHelpFormatter,
    )
    p.add_argument("policy_dir", nargs="?", help="export directory (policy.json, .npz)")
    p.add_argument(
        "--goal",
        nargs=2,
        type=float,
        metavar=("X", "Y"),
        help="goal in the arena frame of policy.json (m)",
    )
    p.add_argument("--replay", metavar="LOG", help="replay a loop log instead of driving")
    p.add_argument(
        "--replay-tolerance",
        type=float,
        default=0.0,
        help="allowed |difference| in replay (default 0: bit-exact)",
    )
    p.add_argument(
        "--rate",
        type=float,
        help="control rate in Hz (default 1 / policy dt); its period may not exceed the "
        "watchdog's --max-scan-age / --max-pose-age",
    )
    p.add_argument("--max-cycles", type=int, help="stop after this many cycles")
    p.add_argument(
        "--no-warm-up",
        dest="warm_up",
        action="store_false",
        help="skip the warm-up pass (zones + actor on the previous cycle's inputs, results "
        "discarded) that brings weights and code back into cache before each cycle",
    )
    _add_sensor_args(p)
    _add_safety_args(p)
    g = p.add_argument_group("drive")
    g.add_argument("--drive", choices=("diff", "ackermann"))
    g.add_argument("--track-width", type=float, metavar="M", help="diff: wheel separation")
    g.add_argument("--max-wheel-speed", type=float, metavar="M/S")
    g.add_argument("--wheelbase", type=float, metavar="M", help="ackermann: axle distance")
    g.add_argument("--max-steer", type=float, metavar="DEG", help="ackermann: steering lock")
    g.add_argument("--dry-run", action="store_true", help="print commands, drive no motors")
    g.add_argument("--motor", metavar="MODULE:FACTORY", help="motor driver factory")
    p.add_argument(
        "--log",
        help="JSONL log, a new file (default advisor-jax-car-<UTC time>.jsonl); an existing "
        "file is never overwritten",
    )
    return p


def _add_sensor_args(p: argparse.ArgumentParser) -> None:
    """The lidar's and the pose tracker's options."""
    g = p.add_argument_group("lidar (RPLIDAR)")
    g.add_argument("--lidar-port", default="/dev/ttyUSB0")
    g.add_argument("--lidar-baud", type=int, default=115200)
    g.add_argument(
        "--lidar-yaw",
        type=float,
        default=0.0,
        metavar="DEG",
        help="robot-frame direction (CCW deg) of the lidar's 0 mark; 180 if reversed; "
        "a multiple of 1/64 deg, the RPLIDAR's angle step",
    )
    g.add_argument(
        "--range-offset",
        type=float,
        metavar="M",
        help="lidar origin to body edge (default: policy.json)",
    )
    g.add_argument("--min-valid", type=int, default=20, help="fewest valid readings per scan")
    g.add_argument("--min-quality", type=float, default=0.0)
    g.add_argument(
        "--min-range",
        type=float,
        default=0.0,
        metavar="M",
        help="drop closer readings (chassis hits; an A2 measures from 0.15 m)",
    )
    g = p.add_argument_group("pose tracker")
    g.add_argument(
        "--pose-udp",
        default="0.0.0.0:5005",
        metavar="HOST:PORT",
        help='listen for {"t", "x", "y", "theta"} JSON datagrams',
    )
    g.add_argument(
        "--max-pose-speed",
        type=float,
        default=3.0,
        metavar="M/S",
        help="faster apparent motion is a tracker glitch",
    )


def _add_safety_args(p: argparse.ArgumentParser) -> None:
    """The watchdog's options and the car's own limits."""
    g = p.add_argument_group("watchdog")
    g.add_argument("--max-scan-age", type=float, default=0.3, metavar="S")
    g.add_argument("--max-pose-age", type=float, default=0.3, metavar="S")
    g.add_argument(
        "--goal-tolerance",
        type=float,
        metavar="M",
        help="stop at the goal (default: T_g of policy.json, else 0.15)",
    )
    g.add_argument(
        "--collision-distance",
        type=float,
        metavar="M",
        help="stop when min zone <= this (default: T_c of policy.json; <0: never)",
    )
    g = p.add_argument_group("the car's own limits (never taken from the policy directory)")
    g.add_argument(
        "--limits",
        metavar="FILE",
        help="operator's JSON file: max_speed (m/s), max_yaw_rate (rad/s), verify_key (a key "
        "file: every export must be signed with it)",
    )
    g.add_argument(
        "--max-speed",
        type=float,
        metavar="M/S",
        help=f"forward speed limit (default {CAR_SPEC['max_speed']:g}, or the limits file)",
    )
    g.add_argument(
        "--max-yaw-rate",
        type=float,
        metavar="RAD/S",
        help=f"yaw-rate limit (default {CAR_SPEC['max_yaw_rate']:g}, or the limits file)",
    )
    g.add_argument(
        "--verify-key",
        metavar="KEYFILE",
        help="refuse any export not signed with this key (advisor-jax export --sign-key)",
    )


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


def drive(args: argparse.Namespace) -> int:
    if args.policy_dir is None or args.goal is None:
        raise ValueError("driving needs POLICY_DIR and --goal X Y")
    drive_model = _drive_from_args(args)  # argument errors before any hardware is touched
    host, port = _host_port(args.pose_udp)
    if args.rate is not None and not (math.isfinite(args.rate) and args.rate > 0):
        raise ValueError(f"--rate {args.rate:g} Hz: the control rate must be a positive number")
    limits, key = limits_from_options(args.limits, args.max_speed, args.max_yaw_rate,
                                      args.verify_key)  # fmt: skip
    policy = load_policy(args.policy_dir, verify_key=key)
    check_policy(os.path.join(args.policy_dir, "policy.json"), policy.v_max, policy.omega_max,
                 limits)  # fmt: skip
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
    builder = ObservationBuilder(obs_cfg, tuple(args.goal))
    collision = _default(args.collision_distance, policy.env, "T_c", None)
    if args.collision_distance is None and collision is not None and not collision >= 0:
        raise ValueError(  # only the operator may turn the collision stop off, never a file
            f"{args.policy_dir}: env.T_c = {collision:g} in policy.json would turn the "
            "collision stop off; give --collision-distance to choose it on the car's side"
        )
    rate = args.rate if args.rate is not None else 1.0 / policy.dt
    loop_cfg = LoopConfig(
        rate_hz=rate,
        max_scan_age=args.max_scan_age,
        max_pose_age=args.max_pose_age,
        goal_tolerance=_default(args.goal_tolerance, policy.env, "T_g", 0.15),
        collision_distance=None if collision is None or collision < 0 else collision,
        max_cycles=args.max_cycles,
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
    if args.dry_run:
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
        scans = hardware.RplidarScanSource(args.lidar_port, baudrate=args.lidar_baud)
        poses = hardware.UdpPoseSource(host, port)
        log = cyclelog.new_log(args.log, PROG)  # a new file, never over an existing one
        log_path = log.path
        log.write(log_header(controller, policy, argv=sys.argv))
        print(
            f"{PROG}: driving to ({args.goal[0]:g}, {args.goal[1]:g}) at {rate:g} Hz within "
            f"the {limits.describe()}; log {log_path}; Ctrl-C stops",
            file=sys.stderr,
        )
        summary = run_loop(controller, scans, poses, motor, log=log)
    except KeyboardInterrupt:
        with signals_ignored():
            print(f"{PROG}: interrupted; motors stopped; log {log_path}", file=sys.stderr)
        return 130
    finally:
        with signals_ignored():
            signal.signal(signal.SIGTERM, previous_handler)
            _shutdown(motor, scans, poses)
            if log is not None:
                log.close()
    stops = ", ".join(f"{k} x{v}" for k, v in summary.stops.items()) or "none"
    print(
        f"{PROG}: ended ({summary.end}) after {summary.cycles} cycles; stops: {stops}; "
        f"overruns: {summary.overruns}; log {log_path}",
        file=sys.stderr,
    )
    return 0


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


def main(argv: Sequence[str] | None = None) -> int:
    args = build_parser().parse_args(argv)
    try:
        return replay_command(args) if args.replay else drive(args)
    except (RunnerError, ValueError, OSError) as e:
        print(f"{PROG}: error: {e}", file=sys.stderr)
        return 2
    except Exception as e:  # the last line of defence: still one line, never a traceback
        print(f"{PROG}: error: unexpected {type(e).__name__}: {e}", file=sys.stderr)
        return 2


if __name__ == "__main__":
    sys.exit(main())
