"""Hardware interfaces and adapters of the car (paper §5.2): lidar, pose tracker, motors.

Interfaces (structural ``Protocol``s; tests pass fakes):

* ``ScanSource.latest() -> Scan | None``: newest complete lidar turn, or None before the first.
* ``PoseSource.latest() -> Pose | None``: newest tracked pose, or None before the first.
* ``MotorDriver.send(command)`` / ``.stop()`` / ``.close()``: ``command`` is a ``DiffCommand``
  or ``AckermannCommand`` (``drive.py``); ``stop()`` must bring the car to rest.

Adapters:

* ``RplidarScanSource``: an RPLIDAR A2 through the ``rplidar`` package (the ``car`` extra,
  imported lazily); a background thread reads ``iter_scans()`` and keeps the newest turn,
  stamped with the loop clock on arrival. Driver errors are re-raised by ``latest()``.
* ``UdpPoseSource``: the external camera tracker sends one UDP datagram per pose, a UTF-8
  JSON object (extra keys ignored)::

      {"t": 12.345, "x": 0.52, "y": -1.10, "theta": 1.571}

  ``t``: the tracker's capture time in seconds on its own clock (only differences are used,
  for the velocity); ``x``, ``y``: metres in the arena frame of ``spec.py`` (origin at the
  arena centre, x right, y up: the frame of policy.json's bounds); ``theta``: heading in
  radians, counter-clockwise from +x. The socket is non-blocking; ``latest()`` drains it and
  keeps the datagram with the newest ``t`` (older ones arriving late are ignored unless
  ``t`` jumped back by more than ``restart_gap`` s: a restarted tracker). A datagram that
  breaks the schema raises ``HardwareError`` from ``latest()`` (the loop stops that cycle).
  Its ``stamp`` is the loop-clock time of the ``latest()`` call that first saw it, so ages
  are under-estimated by at most one loop period.
* ``PrintMotorDriver``: dry run, prints commands; ``load_motor_driver("pkg.mod:factory")``
  plugs in the real motor controller.
"""

from __future__ import annotations

import importlib
import json
import math
import socket
import sys
import threading
import time
from collections.abc import Callable
from typing import IO, Any, Protocol, runtime_checkable

import numpy as np

from advisor_jax.runner.drive import Command
from advisor_jax.runner.errors import HardwareError
from advisor_jax.runner.observation import Pose, Scan


@runtime_checkable
class ScanSource(Protocol):
    def latest(self) -> Scan | None: ...

    def close(self) -> None: ...


@runtime_checkable
class PoseSource(Protocol):
    def latest(self) -> Pose | None: ...

    def close(self) -> None: ...


@runtime_checkable
class MotorDriver(Protocol):
    def send(self, command: Command) -> None: ...

    def stop(self) -> None: ...

    def close(self) -> None: ...


def _rplidar_class():
    try:
        from rplidar import RPLidar
    except ImportError:
        raise HardwareError(
            "the RPLIDAR adapter needs the 'rplidar' package: pip install 'advisor-jax[car]'"
        ) from None
    return RPLidar


class RplidarScanSource:
    """Newest RPLIDAR turn, read by a background thread."""

    def __init__(
        self,
        port: str,
        *,
        baudrate: int = 115200,
        clock: Callable[[], float] = time.monotonic,
        max_buf_meas: int = 3000,
        min_len: int = 5,
        lidar: Any = None,
    ):
        """``lidar``: an object with the ``rplidar.RPLidar`` API (default: open ``port``)."""
        if lidar is None:
            try:
                lidar = _rplidar_class()(port, baudrate=baudrate)
            except HardwareError:
                raise
            except Exception as e:
                raise HardwareError(f"cannot open RPLIDAR on {port}: {e}") from None
        self._lidar, self._clock = lidar, clock
        self._kwargs = {"max_buf_meas": max_buf_meas, "min_len": min_len}
        self._lock = threading.Lock()
        self._stop = threading.Event()
        self._latest: Scan | None = None
        self._error: Exception | None = None
        self._thread = threading.Thread(target=self._run, name="rplidar", daemon=True)
        self._thread.start()

    def _run(self) -> None:
        while not self._stop.is_set():
            try:
                for turn in self._lidar.iter_scans(**self._kwargs):
                    points = np.asarray(turn, dtype=np.float64).reshape(-1, 3)
                    scan = Scan(points, self._clock())
                    with self._lock:
                        self._latest = scan
                    if self._stop.is_set():
                        return
                return  # the iterator ended: the device went away
            except Exception as e:  # noqa: BLE001 - reported through latest()
                with self._lock:
                    self._error = e
                try:  # resynchronise: stop the scan, drop buffered bytes, try again
                    self._lidar.stop()
                    if hasattr(self._lidar, "clean_input"):
                        self._lidar.clean_input()
                except Exception:
                    pass
                self._stop.wait(0.5)

    def latest(self) -> Scan | None:
        with self._lock:
            error, self._error = self._error, None
            scan = self._latest
        if error is not None:
            raise HardwareError(f"RPLIDAR: {type(error).__name__}: {error}")
        return scan

    def close(self) -> None:
        self._stop.set()
        for name in ("stop", "stop_motor", "disconnect"):
            try:
                getattr(self._lidar, name)()
            except Exception:
                pass
        self._thread.join(timeout=2.0)


def parse_pose_datagram(data: bytes, stamp: float) -> Pose:
    """One tracker datagram → Pose; HardwareError naming the problem if it breaks the schema."""
    try:
        msg = json.loads(data.decode("utf-8"))
    except (UnicodeDecodeError, json.JSONDecodeError) as e:
        raise HardwareError(f"pose datagram is not UTF-8 JSON: {e}") from None
    if not isinstance(msg, dict):
        raise HardwareError(f"pose datagram must be a JSON object, got {type(msg).__name__}")
    values = []
    for key in ("x", "y", "theta", "t"):
        v = msg.get(key)
        if isinstance(v, bool) or not isinstance(v, int | float) or not math.isfinite(v):
            raise HardwareError(f"pose datagram field {key!r} = {v!r} is not a finite number")
        values.append(float(v))
    return Pose(*values, stamp=stamp)


class UdpPoseSource:
    """Newest tracker pose from UDP JSON datagrams (schema in the module docstring)."""

    def __init__(
        self,
        host: str = "0.0.0.0",
        port: int = 5005,
        *,
        clock: Callable[[], float] = time.monotonic,
        restart_gap: float = 1.0,
    ):
        self._clock, self._restart_gap = clock, restart_gap
        self._sock = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
        try:
            self._sock.setsockopt(socket.SOL_SOCKET, socket.SO_REUSEADDR, 1)
            self._sock.bind((host, port))
        except OSError as e:
            self._sock.close()
            raise HardwareError(f"cannot listen for poses on UDP {host}:{port}: {e}") from None
        self._sock.setblocking(False)
        self._latest: Pose | None = None

    @property
    def address(self) -> tuple[str, int]:
        return self._sock.getsockname()

    def latest(self) -> Pose | None:
        error = None
        while True:
            try:
                data = self._sock.recv(65536)
            except (BlockingIOError, InterruptedError):
                break
            try:
                pose = parse_pose_datagram(data, self._clock())
            except HardwareError as e:
                error = e
                continue
            last = self._latest
            if last is None or pose.t > last.t or pose.t < last.t - self._restart_gap:
                self._latest = pose
        if error is not None:
            raise error
        return self._latest

    def close(self) -> None:
        self._sock.close()


class PrintMotorDriver:
    """Dry-run motors: prints each command (a stop only when the state changes)."""

    def __init__(self, stream: IO[str] | None = None):
        self._stream = stream
        self.last: Command | None = None
        self.stopped = True
        self.sent = 0

    def _print(self, text: str) -> None:
        print(f"[dry-run] {text}", file=self._stream or sys.stdout, flush=True)

    def send(self, command: Command) -> None:
        self.last, self.stopped = command, False
        self.sent += 1
        fields = " ".join(f"{k}={v:+.3f}" for k, v in command.as_dict().items() if k != "kind")
        self._print(f"{command.as_dict()['kind']} {fields}")

    def stop(self) -> None:
        if not self.stopped:
            self._print("STOP")
        self.last, self.stopped = None, True

    def close(self) -> None:
        self.stop()


def load_motor_driver(target: str, **kwargs: Any) -> MotorDriver:
    """``"package.module:factory"`` → ``factory(**kwargs)``, checked to be a MotorDriver."""
    module_name, _, attr = target.partition(":")
    if not module_name or not attr:
        raise HardwareError(f"motor driver {target!r} must look like 'package.module:factory'")
    try:
        factory = getattr(importlib.import_module(module_name), attr)
    except (ImportError, AttributeError) as e:
        raise HardwareError(f"cannot load motor driver {target!r}: {e}") from None
    driver = factory(**kwargs)
    if not isinstance(driver, MotorDriver):
        raise HardwareError(
            f"{target!r} returned {type(driver).__name__}, which lacks "
            "send(command), stop() and close()"
        )
    return driver
