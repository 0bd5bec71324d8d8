"""Issue 39, class 6 and the car's side of classes 1 and 5: a car that cannot be talked
into unsafe speeds through files in the policy directory.

(a) The car's limits come from its own side (built-in spec, ``--limits FILE``, flags) and
are printed when it starts; a policy asking for more is refused, and the loop stops rather
than send a command beyond them. (b) A signed export (``export_policy(sign_key=...)``,
``--verify-key``) with one changed byte is refused. Also: the control rate may not hold a
command longer than the watchdog allows, the log is always a new file, and a second Ctrl-C
cannot cut the final stop short.
"""

from __future__ import annotations

import json
import os
import shutil
import signal

import numpy as np
import pytest
from runner_fakes import FakeClock, RecordingMotor, ScriptedSource, export_test_actor, moving_pose
from test_cli import DRIVE, FakeLidarSource, FakeTracker
from test_loop import controller, fresh_scan, run

from advisor_jax.runner import cli, hardware
from advisor_jax.runner.policy import load_policy
from advisor_jax.runner.policy_meta import config_hash, metadata_sha256


def forge(export, *, control=None, scale=None, env=None):
    """A consistent forgery, as anyone who can write the policy directory can make one:
    fields edited together and every hash recomputed, so that every check of the export
    itself passes."""
    meta = json.loads((export / "policy.json").read_text())
    meta["control"].update(control or {})
    for head, value in (scale or {}).items():
        next(h for h in meta["heads"] if h["name"] == head)["scale"] = value
    meta["env"].update(env or {})
    meta["config_hash"] = config_hash(meta["config"], meta["env"])
    meta["metadata_sha256"] = metadata_sha256(meta)
    (export / "policy.json").write_text(json.dumps(meta, indent=1))
    load_policy(export)  # the forgery passes every check of the export


def fake_hardware(monkeypatch):
    opened = []

    def lidar(*args, **kw):
        opened.append("lidar")
        return FakeLidarSource(*args, **kw)

    monkeypatch.setattr(hardware, "RplidarScanSource", lidar)
    monkeypatch.setattr(hardware, "UdpPoseSource", FakeTracker)
    return opened


def drive(export, log, *extra):
    args = [str(export), "--goal", "1.5", "0.8", *DRIVE, "--dry-run", "--max-cycles", "3"]
    return cli.main([*args, "--log", str(log), *extra])


def error_line(capsys) -> str:
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and err[0].startswith("advisor-jax-car: error: "), err
    return err[0]


# (a) the car's own limits ----------------------------------------------------------------


@pytest.mark.parametrize(
    ("forgery", "message"),
    [
        (
            {"control": {"v_max": 5.0}, "scale": {"V": 5.0}, "env": {"v_max": 5.0}},
            "control.v_max = 5 is beyond this car's limit of 1 (built-in car spec)",
        ),
        (
            {"control": {"omega_max": 10.0}, "scale": {"omega": 10.0}, "env": {"omega_max": 10.0}},
            "control.omega_max = 10 is beyond this car's limit of 3 (built-in car spec)",
        ),
    ],
    ids=["speed", "yaw-rate"],
)
def test_a_consistent_forgery_cannot_raise_the_cars_limits(
    export_copy, tmp_path, capsys, monkeypatch, forgery, message
):
    forge(export_copy, **forgery)
    opened = fake_hardware(monkeypatch)
    log = tmp_path / "drive.jsonl"
    assert drive(export_copy, log) == 2
    assert message in error_line(capsys)
    assert capsys.readouterr().out == "" and not opened and not log.exists()


def test_the_car_prints_its_limits_and_takes_them_from_its_own_side(
    export_dir, tmp_path, capsys, monkeypatch
):
    fake_hardware(monkeypatch)
    assert drive(export_dir, tmp_path / "a.jsonl", "--rate", "20") == 0
    err = " ".join(capsys.readouterr().err.split())
    assert "within the car limits: speed <= 1 m/s, yaw rate <= 3 rad/s (built-in car spec)" in err
    header = json.loads((tmp_path / "a.jsonl").read_text().splitlines()[0])
    assert header["loop"]["max_speed"] == 1.0 and header["loop"]["max_yaw_rate"] == 3.0
    # The operator lowers a limit below what the policy asks for (v_max 1 m/s): refused.
    assert drive(export_dir, tmp_path / "b.jsonl", "--max-speed", "0.5") == 2
    assert "limit of 0.5 (max_speed from --max-speed)" in error_line(capsys)
    limits = tmp_path / "car-limits.json"
    limits.write_text(json.dumps({"max_yaw_rate": 1.5}))
    assert drive(export_dir, tmp_path / "c.jsonl", "--limits", str(limits)) == 2
    assert f"limit of 1.5 (max_yaw_rate from {limits})" in error_line(capsys)
    limits.write_text(json.dumps({"max_speed": 1.0, "v_max": 5}))
    assert drive(export_dir, tmp_path / "d.jsonl", "--limits", str(limits)) == 2
    assert "unknown key(s) v_max" in error_line(capsys)


def test_a_policy_file_cannot_turn_the_collision_stop_off(export_copy, tmp_path, capsys):
    forge(export_copy, env={"T_c": -1.0})
    assert drive(export_copy, tmp_path / "log.jsonl") == 2
    assert "env.T_c = -1 in policy.json would turn the collision stop off" in error_line(capsys)


def test_evaluate_refuses_an_export_made_for_other_scales(export_copy):
    from types import SimpleNamespace

    from advisor_jax.cli.policy_spec import resolve_policy

    env = SimpleNamespace(config=SimpleNamespace(v_max=1.0, omega_max=2.0, dt=0.05))
    resolve_policy(str(export_copy), env)  # the export's own scales: evaluated
    forge(export_copy, control={"v_max": 5.0}, scale={"V": 5.0}, env={"v_max": 5.0})
    with pytest.raises(ValueError, match="exported with v_max=5 m/s but the arena uses 1"):
        resolve_policy(str(export_copy), env)


def test_the_loop_stops_rather_than_command_beyond_the_limits(policy):
    class Faster:  # a policy object asking for 5 m/s at full scale
        v_max, omega_max, bounds = 5.0, policy.omega_max, policy.bounds

        def act(self, obs):
            return np.array([0.9, 0.0], np.float32)

    clock = FakeClock()
    ctrl = controller(Faster(), max_speed=1.0)
    result = ctrl.cycle(clock.t, fresh_scan(clock)(), moving_pose(clock)())
    assert result.state == "stop" and result.reason == "beyond_car_limits"
    assert result.command is None and "4.5 m/s" in result.message


# (b) signed exports ----------------------------------------------------------------------


@pytest.fixture(scope="module")
def signed(tmp_path_factory, actor_params):
    key_file = tmp_path_factory.mktemp("keys") / "car.key"
    key_file.write_bytes(os.urandom(32))
    out = tmp_path_factory.mktemp("signed") / "policy"
    export_test_actor(actor_params, out, sign_key=key_file.read_bytes().strip())
    return out, key_file


def test_a_signed_export_drives_and_one_changed_byte_is_refused(
    signed, tmp_path, capsys, monkeypatch
):
    export, key = signed
    fake_hardware(monkeypatch)
    assert drive(export, tmp_path / "ok.jsonl", "--rate", "20", "--verify-key", str(key)) == 0
    capsys.readouterr()
    for name in sorted(os.listdir(export)):
        changed = tmp_path / f"changed-{name}"
        shutil.copytree(export, changed)
        data = bytearray((changed / name).read_bytes())
        data[len(data) // 3] ^= 0x20
        (changed / name).write_bytes(bytes(data))
        assert drive(changed, tmp_path / f"{name}.jsonl", "--verify-key", str(key)) == 2, name
        assert "advisor-jax-car: error: " in error_line(capsys)
    forged = tmp_path / "forged"
    shutil.copytree(export, forged)
    forge(forged, control={"v_max": 0.9}, scale={"V": 0.9}, env={"v_max": 0.9})
    assert drive(forged, tmp_path / "forged.jsonl", "--verify-key", str(key)) == 2
    assert "the signature does not match policy.json" in error_line(capsys)


def test_a_car_that_verifies_refuses_an_unsigned_export(export_dir, signed, tmp_path, capsys):
    _, key = signed
    assert drive(export_dir, tmp_path / "x.jsonl", "--verify-key", str(key)) == 2
    assert "policy.sig: missing: the export is not signed" in error_line(capsys)
    limits = tmp_path / "car-limits.json"  # the car's configuration asks for signatures
    limits.write_text(json.dumps({"verify_key": str(key)}))
    assert drive(export_dir, tmp_path / "y.jsonl", "--limits", str(limits)) == 2
    assert "the export is not signed" in error_line(capsys)
    short = tmp_path / "short.key"
    short.write_bytes(b"secret")
    assert drive(export_dir, tmp_path / "z.jsonl", "--verify-key", str(short)) == 2
    assert "a key needs at least 16 bytes" in error_line(capsys)


# The rate, the log, the final stop ----------------------------------------------------------


@pytest.mark.parametrize(
    ("extra", "message"),
    [
        (["--rate", "0"], "--rate 0 Hz: the control rate must be a positive number"),
        (["--rate", "-5"], "--rate -5 Hz: the control rate must be a positive number"),
        (["--rate", "1"], "holds each command for 1 s, longer than the watchdog's data age"),
    ],
)
def test_a_rate_that_holds_commands_past_the_watchdog_is_refused(
    export_dir, tmp_path, capsys, monkeypatch, extra, message
):
    opened = fake_hardware(monkeypatch)
    assert drive(export_dir, tmp_path / "log.jsonl", *extra) == 2
    assert message in error_line(capsys)
    assert not opened and not (tmp_path / "log.jsonl").exists()


def test_a_forged_period_cannot_hold_a_command_either(export_copy, tmp_path, capsys, monkeypatch):
    forge(export_copy, control={"dt": 10.0}, env={"dt": 10.0})  # 1 / dt = 0.1 Hz
    fake_hardware(monkeypatch)
    assert drive(export_copy, tmp_path / "log.jsonl") == 2
    assert "holds each command for 10 s" in error_line(capsys)


def test_the_log_is_always_a_new_file(export_dir, tmp_path, capsys, monkeypatch):
    fake_hardware(monkeypatch)
    old_log = tmp_path / "yesterday.jsonl"
    old_log.write_text("yesterday's drive\n")
    assert drive(export_dir, old_log, "--rate", "20") == 2
    assert "yesterday.jsonl exists already; it is never overwritten" in error_line(capsys)
    assert old_log.read_text() == "yesterday's drive\n"
    export = tmp_path / "policy"
    shutil.copytree(export_dir, export)
    before = (export / "policy.npz").read_bytes()
    assert drive(export, export / "policy.npz", "--rate", "20") == 2
    assert "policy.npz exists already" in error_line(capsys)
    assert (export / "policy.npz").read_bytes() == before
    load_policy(export)


class StopInterruptedOnce(RecordingMotor):
    """A second Ctrl-C lands inside the final stop, before it reaches the motors."""

    def __init__(self):
        super().__init__()
        self.signalled = False

    def stop(self):
        if not self.signalled:
            self.signalled = True
            os.kill(os.getpid(), signal.SIGINT)
        super().stop()


def test_a_second_ctrl_c_cannot_cut_the_final_stop_short(policy, tmp_path):
    clock = FakeClock()
    poses = ScriptedSource([moving_pose(clock)] * 3 + [KeyboardInterrupt()])  # the first one
    motor = StopInterruptedOnce()
    before = signal.getsignal(signal.SIGINT)  # Python's, or SIG_IGN in a background job
    with pytest.raises(KeyboardInterrupt):
        run(controller(policy), ScriptedSource([fresh_scan(clock)]), poses, clock, tmp_path, motor)
    assert motor.signalled and motor.calls[-1] == "stop"
    footer = json.loads((tmp_path / "run.jsonl").read_text().splitlines()[-1])
    assert footer["type"] == "footer" and footer["cycles"] == 3
    assert signal.getsignal(signal.SIGINT) is before
