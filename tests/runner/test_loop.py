"""Control loop on a fake clock: driving, watchdog stops and recovery, logs, replay."""

from __future__ import annotations

import json
import math

import numpy as np
import pytest
from runner_fakes import FakeClock, RecordingMotor, ScriptedSource, moving_pose, ring_scan

from advisor_jax.runner import cli
from advisor_jax.runner.cyclelog import JsonlLog, log_header
from advisor_jax.runner.drive import AckermannDrive, DiffCommand, DiffDrive
from advisor_jax.runner.loop import Controller, LoopConfig, run_loop
from advisor_jax.runner.observation import ObservationBuilder, ObservationConfig, Pose, Scan
from advisor_jax.runner.replay import replay

GOAL = (1.5, 0.8)


def controller(policy, drive=None, **loop):
    cfg = ObservationConfig(range_offset=0.22, bounds=policy.bounds)
    loop = {"goal_tolerance": 0.15, "collision_distance": 0.1, **loop}
    drive = drive or AckermannDrive(0.26, 0.4)
    return Controller(policy, ObservationBuilder(cfg, GOAL), drive, LoopConfig(**loop))


def run(ctrl, scans, poses, clock, tmp_path, motor=None):
    motor = motor or RecordingMotor()
    (tmp_path / "run.jsonl").unlink(missing_ok=True)  # a log is a new file (never reused)
    log = JsonlLog(tmp_path / "run.jsonl")
    log.write(log_header(ctrl, ctrl.policy))
    summary = run_loop(ctrl, scans, poses, motor, log=log, clock=clock, sleep=clock.sleep)
    lines = [json.loads(x) for x in (tmp_path / "run.jsonl").read_text().splitlines()]
    return summary, motor, [r for r in lines if r["type"] == "cycle"], lines[-1]


def fresh_scan(clock, dist=0.9):
    return lambda: ring_scan(dist, clock.t - 0.01)


def test_drives_with_the_policy(policy, tmp_path):
    clock = FakeClock()
    ctrl = controller(policy, drive=DiffDrive(0.4), max_cycles=12)
    summary, motor, cycles, footer = run(
        ctrl,
        ScriptedSource([fresh_scan(clock)]),
        ScriptedSource([moving_pose(clock)]),
        clock,
        tmp_path,
    )
    assert summary.cycles == 12 and summary.end == "max_cycles" and not summary.stops
    assert clock.sleeps == pytest.approx([0.05] * 11)
    assert len(motor.calls) == 13 and motor.calls[-1] == "stop"  # 12 commands + final stop
    for rec, sent in zip(cycles, motor.calls, strict=False):
        obs = np.asarray(rec["obs"], np.float32)
        action = policy.act(obs)
        np.testing.assert_array_equal(np.asarray(rec["action"], np.float32), action)
        v, w = float(action[0]) * 1.0, float(action[1]) * 2.0
        assert sent == DiffCommand(v - 0.2 * w, v + 0.2 * w)
        assert rec["state"] == "run" and rec["command"]["kind"] == "diff"
    # The world-frame velocity of the moving pose (0.4 m/s at θ = 0.3) shows up from cycle 1.
    assert cycles[0]["obs"][18:] == [0.0, 0.0]
    assert cycles[5]["obs"][18:] == pytest.approx([0.4 * math.cos(0.3), 0.4 * math.sin(0.3)])
    assert cycles[0]["obs"][:16] == pytest.approx([0.68] * 16)
    assert footer == {
        "type": "footer",
        "cycles": 12,
        "stops": {},
        "overruns": 0,
        "end": "max_cycles",
    }


def test_watchdog_stops_and_recovers(policy, tmp_path):
    clock = FakeClock()
    good, pose = fresh_scan(clock), moving_pose(clock)

    def stale_scan():
        return ring_scan(0.9, clock.t - 0.5)

    def stale_pose():
        p = pose()
        return Pose(p.x, p.y, p.theta, p.t, clock.t - 0.4)

    def nan_pose():
        p = pose()
        return Pose(math.nan, p.y, p.theta, p.t, p.stamp)

    def nan_scan():
        s = good()
        pts = s.points.copy()
        pts[7, 2] = math.nan
        return Scan(pts, s.stamp)

    scans = [None, good, stale_scan, good, good, nan_scan, good, good, good, good]
    poses = [pose, pose, pose, pose, stale_pose, pose, nan_pose, pose, pose, pose]
    ctrl = controller(policy, max_cycles=10)
    summary, motor, cycles, _ = run(
        ctrl, ScriptedSource(scans), ScriptedSource(poses), clock, tmp_path
    )
    reasons = [c["reason"] for c in cycles]
    assert reasons == [
        "no_scan",
        None,
        "stale_scan",
        None,
        "stale_pose",
        "scan_nan",
        "pose_nan",
        None,
        None,
        None,
    ]
    for c, call in zip(cycles, motor.calls, strict=False):
        assert (call == "stop") == (c["state"] == "stop")
        assert c["message"] if c["state"] == "stop" else c["message"] is None
    assert "500 ms old" in cycles[2]["message"]
    assert summary.stops == {
        "no_scan": 1,
        "stale_scan": 1,
        "stale_pose": 1,
        "scan_nan": 1,
        "pose_nan": 1,
    }


class FlakyPolicy:
    """Wraps the real policy; raises on some calls and returns NaN on others."""

    def __init__(self, policy, raise_on=(), nan_on=()):
        self.policy, self.raise_on, self.nan_on, self.calls = policy, raise_on, nan_on, 0
        self.v_max, self.omega_max = policy.v_max, policy.omega_max
        self.meta, self.directory, self.bounds = policy.meta, policy.directory, policy.bounds

    def act(self, obs):
        self.calls += 1
        if self.calls in self.raise_on:
            raise RuntimeError("BLAS fell over")
        if self.calls in self.nan_on:
            return np.array([np.nan, 0.0], np.float32)
        return self.policy.act(obs)


def test_policy_exception_and_nan_stop_the_car(policy, tmp_path):
    clock = FakeClock()
    flaky = FlakyPolicy(policy, raise_on=(2,), nan_on=(4,))
    ctrl = controller(flaky, max_cycles=5, warm_up=False)  # one act per cycle: calls = cycles
    summary, motor, cycles, _ = run(
        ctrl,
        ScriptedSource([fresh_scan(clock)]),
        ScriptedSource([moving_pose(clock)]),
        clock,
        tmp_path,
    )
    assert [c["reason"] for c in cycles] == [None, "exception", None, "action_invalid", None]
    assert "RuntimeError: BLAS fell over" in cycles[1]["message"]
    assert [c == "stop" for c in motor.calls] == [False, True, False, True, False, True]


def test_source_and_motor_failures(policy, tmp_path):
    clock = FakeClock()
    scans = ScriptedSource([fresh_scan(clock), OSError("serial port vanished"), fresh_scan(clock)])
    motor = RecordingMotor(fail_on_send=3)
    ctrl = controller(policy, max_cycles=6)
    summary, motor, cycles, _ = run(
        ctrl, scans, ScriptedSource([moving_pose(clock)]), clock, tmp_path, motor
    )
    assert cycles[1]["reason"] == "scan_source" and not cycles[1]["ran"]
    assert "serial port vanished" in cycles[1]["io_error"]
    assert cycles[2]["io_error"] is None and cycles[2]["state"] == "run"
    failed = [c for c in cycles if c["io_error"] and c["io_error"].startswith("motor")]
    assert len(failed) == 1 and failed[0]["ran"]
    # After the failed send the loop stopped the motors and carried on.
    k = next(i for i, call in enumerate(motor.calls) if isinstance(call, tuple))
    assert motor.calls[k + 1] == "stop" and summary.cycles == 6
    assert summary.stops["motor_error"] == 1


def test_interrupt_stops_the_motors(policy, tmp_path):
    clock = FakeClock()
    poses = ScriptedSource([moving_pose(clock)] * 3 + [KeyboardInterrupt()])
    ctrl = controller(policy)
    motor = RecordingMotor()
    with pytest.raises(KeyboardInterrupt):
        run(ctrl, ScriptedSource([fresh_scan(clock)]), poses, clock, tmp_path, motor)
    assert motor.calls[-1] == "stop" and len(motor.calls) == 4
    footer = json.loads((tmp_path / "run.jsonl").read_text().splitlines()[-1])
    assert footer["end"] == "interrupted: KeyboardInterrupt" and footer["cycles"] == 3


def test_goal_and_collision_end_the_run(policy, tmp_path):
    clock = FakeClock()
    at_goal = lambda: Pose(GOAL[0] - 0.1, GOAL[1], 0.0, clock.t, clock.t)
    summary, motor, cycles, _ = run(
        controller(policy),
        ScriptedSource([fresh_scan(clock)]),
        ScriptedSource([at_goal]),
        clock,
        tmp_path,
    )
    assert summary.end == "goal_reached" and summary.cycles == 1 and motor.calls == ["stop"] * 2
    assert cycles[0]["state"] == "done"
    summary, motor, cycles, _ = run(
        controller(policy),
        ScriptedSource([fresh_scan(clock, dist=0.3)]),
        ScriptedSource([moving_pose(clock)]),
        clock,
        tmp_path,
    )
    assert summary.end == "collision" and cycles[0]["message"] == "min P = 0.080 m"


def test_overruns_are_counted_not_queued(policy, tmp_path):
    clock = FakeClock()

    def slow_scan():  # reading the lidar takes 80 ms of a 50 ms period
        clock.t += 0.08
        return ring_scan(0.9, clock.t)

    summary, *_ = run(
        controller(policy, max_cycles=4, max_pose_age=1.0),
        ScriptedSource([slow_scan]),
        ScriptedSource([moving_pose(clock)]),
        clock,
        tmp_path,
    )
    assert summary.overruns == 3 and clock.sleeps == []


def _mixed_run(policy, tmp_path, **loop):
    clock = FakeClock()
    pose = moving_pose(clock, speed=0.3)
    rng = np.random.default_rng(0)

    def noisy_scan():  # a new turn every other cycle, some invalid readings
        s = ring_scan(rng.uniform(0.5, 1.3, 16), clock.t - 0.02)
        s.points[rng.random(200) < 0.1, 2] = 0.0
        return s

    held = {}

    def every_other():
        k = int(round((clock.t - 1000.0) / 0.05))
        if k % 2 == 0 or "scan" not in held:
            held["scan"] = noisy_scan()
        return held["scan"]

    scans = [every_other] * 6 + [None, every_other, OSError("glitch")] + [every_other] * 31
    poses = [pose] * 12 + [lambda: Pose(9.0, 0.0, 0.0, clock.t - 1000, clock.t)] + [pose] * 27
    ctrl = controller(policy, max_cycles=40, max_scan_age=0.2, **loop)
    return run(ctrl, ScriptedSource(scans), ScriptedSource(poses), clock, tmp_path)


class SpyPolicy(FlakyPolicy):
    """Records every observation it is given."""

    def __init__(self, policy, **flaky):
        super().__init__(policy, **flaky)
        self.seen = []

    def act(self, obs):
        self.seen.append(np.asarray(obs).tolist())
        return super().act(obs)


def test_warm_up_changes_nothing_but_the_caches(policy, tmp_path):
    def untimed(cycles):
        return [
            {k: v for k, v in c.items() if k not in ("wall", "compute_ms", "warm_ms")}
            for c in cycles
        ]

    (tmp_path / "plain").mkdir(), (tmp_path / "warm").mkdir()
    *_, plain, _ = _mixed_run(policy, tmp_path / "plain", warm_up=False)
    spy = SpyPolicy(policy)
    *_, warmed, _ = _mixed_run(spy, tmp_path / "warm", warm_up=True)
    assert untimed(warmed) == untimed(plain)
    assert all(c["warm_ms"] is None for c in plain) and all(c["warm_ms"] >= 0 for c in warmed)
    # Before each cycle the warm-up runs the actor once on the newest observation so far.
    expected, last = [], None
    for c in plain:
        if last is not None:
            expected.append(last)
        if c["action"] is not None:  # this cycle ran the actor
            expected.append(c["obs"])
        last = c["obs"] if c["obs"] is not None else last
    assert spy.seen == expected and len(expected) > 60


def test_warm_up_never_raises(policy):
    flaky = FlakyPolicy(policy, raise_on=(1,))
    ctrl = controller(flaky)
    bad = ring_scan(0.9, 0.0)
    bad.points[3, 1] = math.nan
    ctrl.warm(bad, np.zeros(20, np.float32))  # scan_nan and "BLAS fell over", both absorbed
    ctrl.warm(None, None)
    assert flaky.calls == 1
    ctrl.warm(ring_scan(0.9, 0.0), np.zeros(20, np.float32))
    assert flaky.calls == 2 and ctrl.builder._prev is None  # stateless: no pose recorded


def test_replay_reproduces_the_log(policy, tmp_path, capsys):
    summary, _, cycles, _ = _mixed_run(policy, tmp_path)
    assert summary.stops and sum(c["state"] == "run" for c in cycles) > 20
    assert sum("points" in c["scan"] for c in cycles if c["scan"]) < len(cycles)  # reuse
    report = replay(tmp_path / "run.jsonl")
    assert report.ok and report.cycles == 40 and report.replayed == 39, report.mismatches
    assert report.driving == sum(c["state"] == "run" for c in cycles)
    assert cli.main(["--replay", str(tmp_path / "run.jsonl")]) == 0
    assert "reproduced exactly" in capsys.readouterr().out
    # A log whose action was altered is reported, not silently accepted.
    lines = (tmp_path / "run.jsonl").read_text().splitlines()
    rec = json.loads(lines[20])
    assert rec["state"] == "run"
    rec["action"][1] = float(np.nextafter(np.float32(rec["action"][1]), np.float32(2)))
    lines[20] = json.dumps(rec)
    (tmp_path / "bad.jsonl").write_text("\n".join(lines) + "\n")
    report = replay(tmp_path / "bad.jsonl")
    assert report.mismatched == 1 and "action differs" in report.mismatches[0]
    assert cli.main(["--replay", str(tmp_path / "bad.jsonl")]) == 1
    assert "replay differs from the log in 1 of 39 cycles" in capsys.readouterr().err
