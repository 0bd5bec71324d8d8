"""Hardware adapters: UDP pose datagrams, the RPLIDAR thread (fake device), motor drivers."""

from __future__ import annotations

import io
import json
import re
import socket
import sys
import threading
import time

import numpy as np
import pytest
from runner_fakes import FakeClock

from advisor_jax.runner import hardware
from advisor_jax.runner.drive import AckermannCommand, DiffCommand
from advisor_jax.runner.errors import HardwareError


@pytest.fixture
def udp():
    clock = FakeClock()
    source = hardware.UdpPoseSource("127.0.0.1", 0, clock=clock)
    sender = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)

    def send(payload):
        data = payload if isinstance(payload, bytes) else json.dumps(payload).encode()
        sender.sendto(data, source.address)

    yield source, send, clock
    sender.close()
    source.close()


def _drain(source, want_t, timeout=2.0):
    """Loopback delivery is asynchronous: poll until the pose with ``want_t`` arrived."""
    deadline = time.monotonic() + timeout
    while time.monotonic() < deadline:
        pose = source.latest()
        if pose is not None and pose.t == want_t:
            return pose
        time.sleep(0.005)
    raise AssertionError(f"no pose with t={want_t} arrived")


def test_udp_pose_keeps_the_newest(udp):
    source, send, clock = udp
    assert source.latest() is None
    send({"t": 1.0, "x": 0.5, "y": -1.0, "theta": 1.5, "id": "ball"})
    pose = _drain(source, 1.0)
    assert (pose.x, pose.y, pose.theta, pose.stamp) == (0.5, -1.0, 1.5, clock.t)
    for t in (2.0, 3.0):
        send({"t": t, "x": t, "y": 0, "theta": 0})
    assert _drain(source, 3.0).x == 3.0
    send({"t": 2.5, "x": 9, "y": 9, "theta": 0})  # late, out of order: ignored
    send({"t": 3.5, "x": 1, "y": 1, "theta": 0})
    assert _drain(source, 3.5).x == 1
    send({"t": 0.1, "x": 2, "y": 2, "theta": 0})  # jumped back > 1 s: tracker restarted
    assert _drain(source, 0.1).x == 2


@pytest.mark.parametrize(
    ("payload", "message"),
    [
        (b"\xff\xfe", "not UTF-8 JSON"),
        (b"[1, 2]", "must be a JSON object"),
        ({"t": 1, "x": 0, "y": 0}, "'theta' = None"),
        ({"t": 1, "x": "0", "y": 0, "theta": 0}, "'x' = '0'"),
        (b'{"t": 1, "x": NaN, "y": 0, "theta": 0}', "'x' = nan"),
        ({"t": True, "x": 0, "y": 0, "theta": 0}, "'t' = True"),
    ],
)
def test_udp_bad_datagrams(udp, payload, message):
    source, send, _ = udp
    send({"t": 1.0, "x": 0.5, "y": 0.5, "theta": 0.0})
    _drain(source, 1.0)
    send(payload)
    send({"t": 2.0, "x": 0.6, "y": 0.5, "theta": 0.0})
    error, deadline = None, time.monotonic() + 2.0
    while time.monotonic() < deadline and (error is None or source.latest().t != 2.0):
        try:
            source.latest()
        except HardwareError as e:
            error = e
        time.sleep(0.005)
    assert error is not None and re.search(message, str(error)), error
    assert source.latest().t == 2.0  # the good datagram after the bad one was kept


def test_udp_port_in_use():
    first = hardware.UdpPoseSource("127.0.0.1", 0)
    try:
        busy = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
        busy.bind(("127.0.0.1", 0))
        port = busy.getsockname()[1]
        with pytest.raises(HardwareError, match=f"cannot listen for poses on UDP 127.0.0.1:{port}"):
            hardware.UdpPoseSource("127.0.0.1", port)
        busy.close()
    finally:
        first.close()


class FakeLidar:
    """The ``rplidar.RPLidar`` API: iter_scans yields lists of (quality, angle, distance)."""

    def __init__(self, turns, fail_after=None):
        self.turns, self.fail_after, self.calls = turns, fail_after, []
        self.done = threading.Event()

    def iter_scans(self, max_buf_meas=3000, min_len=5):
        self.calls.append(("iter_scans", max_buf_meas, min_len))
        for k, turn in enumerate(self.turns):
            if self.fail_after is not None and k == self.fail_after:
                self.fail_after = None
                self.done.set()
                raise RuntimeError("Incorrect descriptor starting bytes")
            yield turn
        self.done.set()
        while True:  # a real lidar keeps turning; block like it does
            time.sleep(0.01)
            if ("stop",) in self.calls:
                return

    def stop(self):
        self.calls.append(("stop",))

    def stop_motor(self):
        self.calls.append(("stop_motor",))

    def disconnect(self):
        self.calls.append(("disconnect",))


def test_rplidar_source_keeps_the_newest_turn():
    turns = [[(15, 10.0 * k + i, 500.0 + i) for i in range(3)] for k in range(4)]
    lidar = FakeLidar(turns)
    clock = FakeClock()
    source = hardware.RplidarScanSource("/dev/null", lidar=lidar, clock=clock, min_len=3)
    assert lidar.done.wait(2.0)  # set only after the thread stored the last turn
    scan = source.latest()
    np.testing.assert_array_equal(scan.points, np.asarray(turns[-1], np.float64))
    assert scan.stamp == clock.t and scan.points.shape == (3, 3)
    source.close()
    assert [c[0] for c in lidar.calls[-3:]] == ["stop", "stop_motor", "disconnect"]
    assert lidar.calls[0] == ("iter_scans", 3000, 3)


def test_rplidar_errors_surface_through_latest():
    lidar = FakeLidar([[(15, 1.0, 500.0)]] * 3, fail_after=1)
    source = hardware.RplidarScanSource("/dev/null", lidar=lidar)
    assert lidar.done.wait(2.0)
    error, deadline = None, time.monotonic() + 2.0
    while error is None and time.monotonic() < deadline:
        try:
            source.latest()
        except HardwareError as e:
            error = e
        time.sleep(0.005)
    assert "RPLIDAR: RuntimeError: Incorrect descriptor" in str(error)
    assert source.latest() is not None  # reported once; the last good turn is kept
    source.close()


def test_rplidar_package_missing(monkeypatch):
    monkeypatch.setitem(sys.modules, "rplidar", None)
    with pytest.raises(HardwareError, match=r"needs the 'rplidar' package: pip install"):
        hardware.RplidarScanSource("/dev/ttyUSB0")


def test_print_motor_driver():
    out = io.StringIO()
    motor = hardware.PrintMotorDriver(out)
    motor.stop()  # already at rest: nothing printed
    motor.send(DiffCommand(0.25, -0.5))
    motor.send(AckermannCommand(0.5, 0.1))
    motor.stop()
    motor.stop()
    assert out.getvalue().splitlines() == [
        "[dry-run] diff left=+0.250 right=-0.500",
        "[dry-run] ackermann speed=+0.500 steering=+0.100",
        "[dry-run] STOP",
    ]
    assert isinstance(motor, hardware.MotorDriver)


def test_load_motor_driver():
    driver = hardware.load_motor_driver("advisor_jax.runner.hardware:PrintMotorDriver")
    assert isinstance(driver, hardware.PrintMotorDriver)
    with pytest.raises(HardwareError, match="must look like"):
        hardware.load_motor_driver("no_colon")
    with pytest.raises(HardwareError, match="cannot load motor driver"):
        hardware.load_motor_driver("advisor_jax.nope:Driver")
    with pytest.raises(HardwareError, match="lacks send"):
        hardware.load_motor_driver("collections:OrderedDict")
