"""The options of ``advisor-jax-car`` (argparse only: no tyro on the car)."""

from __future__ import annotations

import argparse

from advisor_jax.runner.limits import CAR_SPEC

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

--sim needs no car: the same loop drives the simulated physical arena of
policy.json (its lidar scans, tracked poses, motors and clock), to --goal or the
episode of --seed, and writes the same log.

examples:
  advisor-jax-car runs/export --goal 1.5 0.8 --drive ackermann --wheelbase 0.26 \\
      --max-steer 25 --motor mycar.motors:make_driver
  advisor-jax-car results/policy_physical_atd3_afdp --sim --seed 3 --log sim.jsonl
  advisor-jax-car --replay docs/examples/sim_drive.jsonl results/policy_physical_atd3_afdp
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
    p.add_argument(
        "--max-cycles",
        type=int,
        help="stop after this many cycles (--sim: default the policy's h_max, as an episode)",
    )
    p.add_argument(
        "--sim",
        action="store_true",
        help="no car: drive the simulated physical arena of policy.json with this same loop "
        "(lidar scans, tracked poses, motors and clock simulated; needs the full install); "
        "--goal defaults to the episode's",
    )
    p.add_argument(
        "--seed",
        type=int,
        default=0,
        help="--sim: the episode (start pose and goal) of this seed (default 0)",
    )
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
