"""advisor-jax-car: one-line errors, a dry run with fake sensors, replay of its log."""

from __future__ import annotations

import json
import math
import sys
import time

import pytest
from runner_fakes import ring_scan

from advisor_jax.runner import cli, hardware
from advisor_jax.runner.observation import Pose

DRIVE = ["--drive", "ackermann", "--wheelbase", "0.26", "--max-steer", "25"]


def _error_line(capsys) -> str:
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "Traceback" not in err[0], err
    assert err[0].startswith("advisor-jax-car: error: ")
    return err[0]


@pytest.mark.parametrize(
    ("args", "message"),
    [
        ([], "driving needs POLICY_DIR and --goal"),
        (["{dir}", "--goal", "0", "0"], "choose --drive diff or --drive ackermann"),
        (["{dir}", "--goal", "0", "0", "--drive", "diff"], "needs --track-width"),
        (["{dir}", "--goal", "0", "0", "--drive", "ackermann"], "needs --wheelbase"),
        (["{dir}", "--goal", "0", "0", *DRIVE, "--pose-udp", "5005"], "HOST:PORT"),
        (["{dir}", "--goal", "0", "0", *DRIVE], "no motor driver"),
        (["{dir}", "--goal", "5", "0", *DRIVE, "--dry-run"], "outside the arena bounds"),
        (["{dir}", "--goal", "0", "0", *DRIVE, "--lidar-yaw", "2.3"], "multiple of 1/64 degree"),
        (["{dir}/nope", "--goal", "0", "0", *DRIVE, "--dry-run"], "not a directory"),
        (["--replay", "{dir}/missing.jsonl"], "cannot read log"),
    ],
)
def test_errors_are_one_line(export_dir, capsys, args, message):
    args = [a.replace("{dir}", str(export_dir)) for a in args]
    assert cli.main(args) == 2
    assert message in _error_line(capsys)


def test_lidar_unavailable_is_one_line(export_dir, capsys, monkeypatch):
    monkeypatch.setitem(sys.modules, "rplidar", None)
    args = [str(export_dir), "--goal", "0", "0", *DRIVE, "--dry-run", "--pose-udp", "127.0.0.1:0"]
    assert cli.main(args) == 2
    assert "needs the 'rplidar' package" in _error_line(capsys)


class FakeLidarSource:
    def __init__(self, port, baudrate=115200):
        self.closed = False

    def latest(self):
        return ring_scan(0.9, time.monotonic() - 0.01)

    def close(self):
        self.closed = True


class FakeTracker:
    def __init__(self, host, port):
        self.t0 = time.monotonic()

    def latest(self):
        now = time.monotonic()
        t = now - self.t0
        return Pose(-1.0 + 0.3 * t * math.cos(0.2), -0.5 + 0.3 * t * math.sin(0.2), 0.2, t, now)

    def close(self):
        pass


def _dry_run(monkeypatch, export_dir, log, cycles: int, *extra: str) -> list[str]:
    """Drives ``cycles`` cycles with the fake lidar and tracker; returns the base arguments."""
    monkeypatch.setattr(hardware, "RplidarScanSource", FakeLidarSource)
    monkeypatch.setattr(hardware, "UdpPoseSource", FakeTracker)
    args = [str(export_dir), "--goal", "1.5", "0.8", *DRIVE, "--dry-run", "--max-cycles"]
    args.append(str(cycles))
    assert cli.main([*args, "--log", str(log), "--rate", "50", *extra]) == 0
    return args


def test_dry_run_then_replay(export_dir, tmp_path, capsys, monkeypatch):
    log = tmp_path / "drive.jsonl"
    args = _dry_run(monkeypatch, export_dir, log, 6)
    captured = capsys.readouterr()
    printed = captured.out.splitlines()
    assert len(printed) == 7 and printed[-1] == "[dry-run] STOP"
    assert all(line.startswith("[dry-run] ackermann speed=") for line in printed[:6])
    assert "differs from the training rate 20 Hz" in captured.err
    assert "ended (max_cycles) after 6 cycles" in captured.err
    lines = [json.loads(x) for x in log.read_text().splitlines()]
    header, cycles, footer = lines[0], lines[1:-1], lines[-1]
    assert header["goal"] == [1.5, 0.8] and header["drive"]["max_steering"] == math.radians(25)
    assert header["loop"]["goal_tolerance"] == 0.15 and header["loop"]["collision_distance"] == 0.1
    assert header["observation"]["range_offset"] == 0.22
    assert len(cycles) == 6 and all(c["state"] == "run" for c in cycles)
    assert header["loop"]["warm_up"] and all(c["warm_ms"] >= 0 for c in cycles)
    assert footer["end"] == "max_cycles"
    cold = tmp_path / "cold.jsonl"
    assert cli.main([*args, "--log", str(cold), "--no-warm-up"]) == 0
    lines = [json.loads(x) for x in cold.read_text().splitlines()]
    assert lines[0]["loop"]["warm_up"] is False and all(c["warm_ms"] is None for c in lines[1:-1])
    capsys.readouterr()
    assert cli.main(["--replay", str(log)]) == 0
    assert "replayed 6 of 6 cycles (6 driving)" in capsys.readouterr().out
    # A log recorded with other weights cannot be replayed with this policy.
    header["weights_sha256"] = "0" * 64
    log.write_text("\n".join(json.dumps(x) for x in [header, *cycles, footer]) + "\n")
    assert cli.main(["--replay", str(log), str(export_dir)]) == 2
    assert "is not the one the log was recorded with" in _error_line(capsys)


# Issue 20 -----------------------------------------------------------------------------


def test_car_refuses_an_export_with_edited_limits(export_copy, capsys, monkeypatch):
    """v_max 1 → 5 in policy.json (hash recomputed, as a careful editor would): the car
    refuses before touching any hardware, and no motor command is printed."""
    from advisor_jax.runner.policy_meta import metadata_sha256

    opened = []
    monkeypatch.setattr(hardware, "RplidarScanSource", lambda *a, **k: opened.append(a))
    monkeypatch.setattr(hardware, "UdpPoseSource", lambda *a, **k: opened.append(a))
    meta = json.loads((export_copy / "policy.json").read_text())
    meta["control"]["v_max"] = 5.0
    meta["metadata_sha256"] = metadata_sha256(meta)
    (export_copy / "policy.json").write_text(json.dumps(meta))
    args = [str(export_copy), "--goal", "1.5", "0.8", *DRIVE, "--dry-run", "--max-cycles", "3"]
    assert cli.main(args) == 2
    line = _error_line(capsys)
    assert "control.v_max=5.0 differs from v_max=1.0 the actor was trained with" in line
    assert capsys.readouterr().out == "" and not opened


def test_replay_of_random_bytes_names_the_file(tmp_path, capsys):
    log = tmp_path / "noise.jsonl"
    log.write_bytes(bytes(range(256)) * 4)
    assert cli.main(["--replay", str(log)]) == 2
    assert f"{log}: not a loop log (not UTF-8 text" in _error_line(capsys)
    log.write_text('[1, 2]\n{"type": "cycle"}\n')
    assert cli.main(["--replay", str(log)]) == 2
    assert f"{log}:1: not a JSON object" in _error_line(capsys)


def test_replay_of_a_log_without_cycles_is_not_success(export_dir, tmp_path, capsys, monkeypatch):
    log = tmp_path / "drive.jsonl"
    _dry_run(monkeypatch, export_dir, log, 2)
    capsys.readouterr()
    header, *cycles, footer = [json.loads(x) for x in log.read_text().splitlines()]
    log.write_text(json.dumps(header) + "\n")  # header only: the loop never ran a cycle
    assert cli.main(["--replay", str(log)]) == 2
    assert "no cycles to replay: the log holds only its header" in _error_line(capsys)
    failed = [{**c, "ran": False} for c in cycles]  # every cycle lost a source
    log.write_text("\n".join(json.dumps(x) for x in [header, *failed, footer]) + "\n")
    assert cli.main(["--replay", str(log)]) == 2
    assert "in all 2 cycles a source failed" in _error_line(capsys)
    del cycles[1]["t"]
    log.write_text("\n".join(json.dumps(x) for x in [header, *cycles, footer]) + "\n")
    assert cli.main(["--replay", str(log)]) == 2
    assert f"{log}: cycle record 1 is malformed (missing field 't')" in _error_line(capsys)


def test_range_offset_other_than_training_is_warned(export_dir, tmp_path, capsys, monkeypatch):
    _dry_run(monkeypatch, export_dir, tmp_path / "log.jsonl", 1, "--range-offset", "0.3")
    err = " ".join(capsys.readouterr().err.split())
    assert "--range-offset 0.3 m differs from the 0.22 m the policy was trained with" in err
    assert "reads 0.08 m nearer than in training" in err
