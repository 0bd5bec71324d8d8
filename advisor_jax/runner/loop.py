"""Fixed-rate control loop with a watchdog (paper §5.2: the car runs the actor on board).

Each cycle (period 1 / rate_hz, default the training dt)::

    warm-up (warm_up): zones + actor once on the previous cycle's scan and obs, discarded
    now  = clock()
    scan = scans.latest();  pose = poses.latest()            # newest data + timestamps
    watchdog: no data / stale (age > max_*_age) / invalid     → STOP, reason logged
    obs  = builder.build(scan, pose)                          # observation.py
    goal reached (d ≤ goal_tolerance) or collision (min P ≤ collision_distance)
                                                              → STOP, loop ends ("done")
    a    = policy.act(obs);  (v, w) = a · (v_max, omega_max)  # NaN / out of box → STOP
    (v, w) beyond the car's own limits (max_speed, max_yaw_rate)  → STOP (limits.py)
    motor.send(drive.command(v, w))
    log one JSONL record; sleep until the next deadline (overruns are counted, not queued)

Any exception inside a cycle (a source, the policy, the drive, the motor) stops the motors
for that cycle and is logged; the next cycle with fresh, valid data drives again. Whatever
ends the loop (goal, collision, max_cycles, Ctrl-C, a failing log file), a ``finally`` sends
a last stop, with SIGINT and SIGTERM ignored until it is sent and the log closed (a second
Ctrl-C must not cut the stop short). A command is never held longer than the watchdog's
data age limit: the period 1 / rate_hz may not exceed max_scan_age or max_pose_age.
The clock and sleep are injectable so the tests run on a fake clock.
``Controller.cycle`` is deterministic given (now, scan, pose): ``replay`` re-runs it on a log.
"""

from __future__ import annotations

import collections
import contextlib
import dataclasses
import math
import signal
import threading
import time
from collections.abc import Callable
from typing import Any, Protocol

import numpy as np

from advisor_jax.contract import spec
from advisor_jax.runner import cyclelog
from advisor_jax.runner.drive import Command, Drive, to_physical
from advisor_jax.runner.errors import ObservationError, PolicyError
from advisor_jax.runner.hardware import MotorDriver, PoseSource, ScanSource
from advisor_jax.runner.limits import CAR_SPEC, within
from advisor_jax.runner.observation import ObservationBuilder, Pose, Scan, check_fresh

RUN, STOP, DONE = "run", "stop", "done"


class PolicyLike(Protocol):
    v_max: float
    omega_max: float

    def act(self, obs: np.ndarray) -> np.ndarray: ...


@dataclasses.dataclass(frozen=True)
class LoopConfig:
    """Timing and watchdog limits of the control loop."""

    rate_hz: float = 1.0 / spec.CONTROL_DT
    """Control rate; use the policy's 1 / dt (the velocity inputs were trained at it)."""
    max_scan_age: float = 0.3
    """s; an older scan stops the car (an RPLIDAR A2 turns at ~10 Hz)."""
    max_pose_age: float = 0.3
    """s; an older tracked pose stops the car."""
    goal_tolerance: float | None = None
    """m; d ≤ this ends the run at the goal (T_g of policy.json). None: never."""
    collision_distance: float | None = None
    """m; min zone ≤ this ends the run as a collision (T_c). None: never."""
    max_cycles: int | None = None
    """End after this many cycles (None: run until goal, collision or Ctrl-C)."""
    max_speed: float = CAR_SPEC["max_speed"]
    """m/s; the car's own speed limit (``limits.CarLimits``): a faster command is a stop."""
    max_yaw_rate: float = CAR_SPEC["max_yaw_rate"]
    """rad/s; the car's own yaw-rate limit: a faster turn is a stop."""
    warm_up: bool = True
    """Before each cycle, run its stateless heavy parts (zone reduction, actor) once on the
    previous cycle's scan and observation and discard the results (``Controller.warm``).
    After the idle part of the period the weights and numpy's code are out of the caches;
    this pass brings them back before the sources are read, so the cycle from data to
    command runs warm (experiments/bench_runner.py: the after-sleep rows). Costs about one
    more cold observation + MLP of CPU per cycle."""

    def __post_init__(self):
        for name in ("rate_hz", "max_scan_age", "max_pose_age", "max_speed", "max_yaw_rate"):
            value = getattr(self, name)
            if not math.isfinite(value) or value <= 0:
                raise ValueError(f"LoopConfig.{name}={value!r} must be a positive number")
        hold = min(self.max_scan_age, self.max_pose_age)
        if 1.0 / self.rate_hz > hold:
            raise ValueError(
                f"a control rate of {self.rate_hz:g} Hz holds each command for "
                f"{1.0 / self.rate_hz:g} s, longer than the watchdog's data age limit of "
                f"{hold:g} s (max scan/pose age): the car would drive on without a check; use "
                f"a rate of at least {1.0 / hold:g} Hz"
            )
        for name in ("goal_tolerance", "collision_distance"):
            value = getattr(self, name)
            if value is not None and not (math.isfinite(value) and value >= 0):
                raise ValueError(f"LoopConfig.{name}={value!r} must be >= 0 or None")
        if self.max_cycles is not None and self.max_cycles < 1:
            raise ValueError(f"LoopConfig.max_cycles={self.max_cycles} must be >= 1 or None")


@dataclasses.dataclass
class CycleResult:
    """What one cycle decided. ``command`` is None whenever the motors must stop."""

    state: str
    reason: str | None = None
    message: str | None = None
    obs: np.ndarray | None = None
    action: np.ndarray | None = None
    physical: tuple[float, float] | None = None
    command: Command | None = None


class Controller:
    """Watchdog + observation + policy + drive conversion, without any I/O."""

    def __init__(
        self, policy: PolicyLike, builder: ObservationBuilder, drive: Drive, config: LoopConfig
    ):
        self.policy, self.builder, self.drive, self.config = policy, builder, drive, config

    def describe(self) -> dict:
        """Everything replay needs to rebuild this controller (goes into the log header)."""
        return {
            "goal": list(self.builder.goal),
            "observation": dataclasses.asdict(self.builder.config),
            "drive": self.drive.describe(),
            "loop": dataclasses.asdict(self.config),
        }

    def warm(self, scan: Scan | None, obs: np.ndarray | None) -> None:
        """Runs the zone reduction on ``scan`` and the actor on ``obs`` and discards both
        (``LoopConfig.warm_up``). Both are stateless: the builder's pose history and every
        later cycle's result are untouched. Never raises: whatever is wrong with these
        inputs was already reported by the cycle that produced them."""
        for part, arg in ((self.builder.zones, scan), (self.policy.act, obs)):
            if arg is not None:
                try:
                    part(arg)
                except Exception:  # noqa: BLE001 - a warm-up's failure changes nothing
                    pass

    def cycle(self, now: float, scan: Scan | None, pose: Pose | None) -> CycleResult:
        cfg = self.config
        try:
            if scan is None:
                return CycleResult(STOP, "no_scan", "no lidar scan received yet")
            if pose is None:
                return CycleResult(STOP, "no_pose", "no tracked pose received yet")
            check_fresh("scan", scan.stamp, now, cfg.max_scan_age)
            check_fresh("pose", pose.stamp, now, cfg.max_pose_age)
            obs = self.builder.build(scan, pose)
        except ObservationError as e:
            return CycleResult(STOP, e.reason, str(e))
        except Exception as e:  # never let a surprise reach the motors
            return CycleResult(STOP, "exception", f"{type(e).__name__}: {e}")
        d, p_min = float(obs[spec.OBS_GOAL_DISTANCE]), min(obs[spec.OBS_PROXIMITY].tolist())
        if cfg.goal_tolerance is not None and d <= cfg.goal_tolerance:
            return CycleResult(DONE, "goal_reached", f"d = {d:.3f} m", obs=obs)
        if cfg.collision_distance is not None and p_min <= cfg.collision_distance:
            return CycleResult(DONE, "collision", f"min P = {p_min:.3f} m", obs=obs)
        try:
            action = self.policy.act(obs)
        except PolicyError as e:
            return CycleResult(STOP, "policy_error", str(e), obs=obs)
        except Exception as e:
            return CycleResult(STOP, "exception", f"policy: {type(e).__name__}: {e}", obs=obs)
        try:
            physical = to_physical(action, self.policy.v_max, self.policy.omega_max)
        except (ValueError, TypeError, IndexError) as e:
            return CycleResult(STOP, "action_invalid", str(e), obs=obs, action=action)
        if not within(*physical, cfg.max_speed, cfg.max_yaw_rate):
            v, w = physical
            return CycleResult(
                STOP,
                "beyond_car_limits",
                f"(v, w) = ({v:.3g} m/s, {w:.3g} rad/s) is beyond the car's limits "
                f"({cfg.max_speed:g} m/s, {cfg.max_yaw_rate:g} rad/s)",
                obs,
                action,
                physical,
            )
        try:
            command = self.drive.command(*physical)
        except Exception as e:
            return CycleResult(
                STOP, "exception", f"drive: {type(e).__name__}: {e}", obs, action, physical
            )
        return CycleResult(RUN, None, None, obs, action, physical, command)


@dataclasses.dataclass
class LoopSummary:
    cycles: int = 0
    stops: collections.Counter = dataclasses.field(default_factory=collections.Counter)
    overruns: int = 0
    end: str = "running"

    def as_dict(self) -> dict:
        return {
            "cycles": self.cycles,
            "stops": dict(self.stops),
            "overruns": self.overruns,
            "end": self.end,
        }


def _latest(source: ScanSource | PoseSource, what: str) -> tuple[Any, str | None]:
    try:
        return source.latest(), None
    except Exception as e:  # a dead driver is a stop, not a crash
        return None, f"{what} source: {type(e).__name__}: {e}"


def run_loop(
    controller: Controller,
    scans: ScanSource,
    poses: PoseSource,
    motor: MotorDriver,
    *,
    log: cyclelog.JsonlLog | None = None,
    clock: Callable[[], float] = time.monotonic,
    sleep: Callable[[float], None] = time.sleep,
) -> LoopSummary:
    """Runs the control loop until goal, collision, ``max_cycles`` or an interrupt."""
    summary = LoopSummary()
    period = 1.0 / controller.config.rate_hz
    logged_scan: Scan | None = None
    warm_scan: Scan | None = None
    warm_obs: np.ndarray | None = None
    deadline = clock()
    try:
        while True:
            if controller.config.warm_up:
                warm_started = time.perf_counter()
                controller.warm(warm_scan, warm_obs)
                warm_ms = (time.perf_counter() - warm_started) * 1e3
            else:
                warm_ms = None
            now = clock()
            started = time.perf_counter()
            scan, scan_err = _latest(scans, "scan")
            pose, pose_err = _latest(poses, "pose")
            io_error = scan_err or pose_err
            ran = io_error is None
            if ran:
                result = controller.cycle(now, scan, pose)
            else:
                reason = "scan_source" if scan_err else "pose_source"
                result = CycleResult(STOP, reason, io_error)
            try:
                if result.command is not None:
                    motor.send(result.command)
                else:
                    motor.stop()
            except Exception as e:
                io_error = f"motor: {type(e).__name__}: {e}"
                summary.stops["motor_error"] += 1
                _stop_quietly(motor)
            compute_ms = (time.perf_counter() - started) * 1e3
            if result.obs is not None:
                warm_scan, warm_obs = scan, result.obs
            summary.cycles += 1
            if result.state != RUN:
                summary.stops[result.reason] += 1
            if log is not None:
                new_scan = scan is not logged_scan
                log.write(
                    cyclelog.cycle_record(
                        summary.cycles - 1,
                        now,
                        scan,
                        pose,
                        result,
                        ran,
                        io_error,
                        with_points=new_scan,
                        compute_ms=compute_ms,
                        warm_ms=warm_ms,
                    )
                )
                logged_scan = scan if scan is not None else logged_scan
            if result.state == DONE:
                summary.end = result.reason or "done"
                break
            if controller.config.max_cycles and summary.cycles >= controller.config.max_cycles:
                summary.end = "max_cycles"
                break
            deadline += period
            delay = deadline - clock()
            if delay > 0:
                sleep(delay)
            else:  # late: start the next cycle now, and do not try to catch up
                summary.overruns += 1
                deadline = clock()
    except BaseException as e:
        summary.end = f"interrupted: {type(e).__name__}"
        raise
    finally:
        with signals_ignored():
            _stop_quietly(motor)
            if log is not None:
                try:
                    log.write({"type": "footer", **summary.as_dict()})
                finally:
                    log.close()
    return summary


@contextlib.contextmanager
def signals_ignored():
    """Ignores SIGINT and SIGTERM for the block (the car's stop and shutdown): a second
    Ctrl-C landing there would raise inside it and leave the motors running. Main thread
    only (elsewhere no handler can be set, nor does a signal land)."""
    if threading.current_thread() is not threading.main_thread():
        yield
        return
    signals = (signal.SIGINT, signal.SIGTERM)
    previous = {s: signal.signal(s, signal.SIG_IGN) for s in signals}
    try:
        yield
    finally:
        for s, handler in previous.items():
            signal.signal(s, handler)


def _stop_quietly(motor: MotorDriver) -> None:
    try:
        motor.stop()
    except Exception:  # nothing more can be done from here; the next cycle tries again
        pass
