"""Issue 20: no silent corruption and no lost runs (checksums, run lock, signals, options).

Every run here is the session's TINY configuration with five seeds, the shapes of the
``population`` fixture, so ``run_training`` reuses its compiled functions.
"""

from __future__ import annotations

import json
import os
import re
import shutil
import signal
import socket
import subprocess
import sys
import textwrap

import jax
import numpy as np
import pytest

from advisor_jax.cli.main import main as cli_main
from advisor_jax.cli.train import TrainArgs, build_run
from advisor_jax.training import checkpoint, interrupts, reporting, runlock
from advisor_jax.training.host_loop import run_training
from advisor_jax.training.population import agent_keys, parse_assignments, seed_key
from advisor_jax.training.runlock import Interrupted
from tests.training.conftest import RUN_HP, RUN_SEEDS, TINY, run_chunks, train_tiny


def _final_params(out):
    return jax.tree_util.tree_leaves(jax.device_get(checkpoint.load_tree(out / "params")))


def _assert_same_params(out_a, out_b):
    for a, b in zip(_final_params(out_a), _final_params(out_b), strict=True):
        np.testing.assert_array_equal(a, b)


def _flip_bit(directory, skip=checkpoint.CHECKSUMS) -> None:
    """Flips one bit in the middle of the largest file below ``directory``."""
    files = [p for p in directory.rglob("*") if p.is_file() and p.name != skip]
    target = max(files, key=lambda p: p.stat().st_size)
    data = bytearray(target.read_bytes())
    data[len(data) // 2] ^= 0x08
    target.write_bytes(bytes(data))


# 2: checksums of params/ and checkpoints/ ---------------------------------------------


def test_corrupt_params_are_refused_by_load_and_export(straight_run, tmp_path, capsys):
    out = tmp_path / "run"
    shutil.copytree(straight_run, out)
    assert checkpoint.verify_checksums(out / "params")
    _flip_bit(out / "params")
    with pytest.raises(ValueError, match=r"parameters at .*params are corrupt: .* has sha256"):
        checkpoint.load_tree(out / "params")
    with pytest.raises(SystemExit) as exit_info:
        cli_main(["export", str(out), "--out", str(tmp_path / "policy")])
    assert exit_info.value.code == 2
    assert "are corrupt" in capsys.readouterr().err
    assert not (tmp_path / "policy").exists()


def test_truncated_params_file_is_one_short_line(straight_run, tmp_path):
    params = tmp_path / "params"
    shutil.copytree(straight_run / "params", params)
    files = [p for p in params.rglob("*") if p.is_file() and p.name != checkpoint.CHECKSUMS]
    target = max(files, key=lambda p: p.stat().st_size)
    target.write_bytes(target.read_bytes()[:40])
    with pytest.raises(ValueError, match="are corrupt") as info:
        checkpoint.load_tree(params)
    # Without checksums (an older save) orbax's TensorStore error is cut to one line.
    (params / checkpoint.CHECKSUMS).unlink()
    with pytest.warns(UserWarning, match="no recorded checksums"):
        with pytest.raises(ValueError, match="are unreadable") as info:
            checkpoint.load_tree(params)
    message = str(info.value)
    assert "\n" not in message and len(message) < 400, message


def test_corrupt_latest_checkpoint_falls_back_to_the_previous(population, tmp_path, tiny_functions):
    _, hp, seeds = population
    _, init_fn, chunk_fn = tiny_functions
    keys = agent_keys(seeds)
    first = run_chunks(init_fn, chunk_fn, keys, hp, n_chunks=1)
    first_host = jax.device_get(first)
    second = run_chunks(init_fn, chunk_fn, keys, hp, n_chunks=2, state=first, first=1)
    ckpts = tmp_path / "checkpoints"
    checkpoint.save_step(ckpts, 40, first_host)
    checkpoint.save_step(ckpts, 80, second)
    _flip_bit(ckpts / "80")
    reports = []
    restored, step = checkpoint.restore_latest(
        ckpts, jax.eval_shape(init_fn, keys), report=reports.append
    )
    assert step == 40
    assert len(reports) == 1 and "checkpoint at step 80 is corrupt" in reports[0]
    assert "resuming from the previous good checkpoint, step 40" in reports[0]
    for a, b in zip(
        jax.tree_util.tree_leaves(jax.device_get(restored)),
        jax.tree_util.tree_leaves(first_host),
        strict=True,
    ):
        np.testing.assert_array_equal(a, b)
    assert sorted(os.listdir(ckpts)) == ["40", "80.corrupt"]
    checkpoint.save_step(ckpts, 80, second)  # the resumed run can save step 80 again
    assert checkpoint.verify_checksums(ckpts / "80")
    # With every checkpoint bad, nothing is renamed and the error lists each one.
    _flip_bit(ckpts / "40")
    _flip_bit(ckpts / "80")
    with pytest.raises(ValueError, match=r"no usable checkpoint .*step 80: .*step 40: "):
        checkpoint.restore_latest(ckpts, jax.eval_shape(init_fn, keys))
    assert sorted(os.listdir(ckpts)) == ["40", "80", "80.corrupt"]


# 3: one run per directory -------------------------------------------------------------

HOLDER = textwrap.dedent(
    """
    import sys
    from advisor_jax.training import runlock
    with runlock.exclusive(sys.argv[1]):
        print("held", flush=True)
        sys.stdin.read()
    """
)


def test_second_run_into_a_held_directory_is_refused(straight_run, tmp_path, tiny_functions):
    out = tmp_path / "run"
    out.mkdir()
    shutil.copy(straight_run / "run.json", out / "run.json")  # a run in progress
    holder = subprocess.Popen(
        [sys.executable, "-c", HOLDER, str(out)],
        stdin=subprocess.PIPE,
        stdout=subprocess.PIPE,
        text=True,
        cwd=os.path.dirname(os.path.dirname(os.path.dirname(__file__))),
    )
    try:
        assert holder.stdout.readline().strip() == "held"
        expected = rf"{out} is in use by another run: pid {holder.pid} on host "
        with pytest.raises(runlock.RunDirectoryBusy, match=expected) as info:
            train_tiny(out, tiny_functions)
        assert socket.gethostname() in str(info.value)
        with pytest.raises(runlock.RunDirectoryBusy, match=f"pid {holder.pid}"):
            train_tiny(out, tiny_functions, resume=True)
        assert sorted(os.listdir(out)) == [runlock.LOCK_FILE, "run.json"]  # nothing written
    finally:
        holder.kill()  # like kill -9: the kernel drops the lock with the process
        holder.wait()
    with runlock.exclusive(out) as info:
        assert info["pid"] == os.getpid()
        with pytest.raises(runlock.RunDirectoryBusy, match=f"pid {os.getpid()}"):
            with runlock.exclusive(out):
                pass


# 5: signals and runs killed before their first checkpoint -----------------------------


def _stop_after_first_chunk(monkeypatch, stop):
    real = reporting.chunk_line

    def chunk_line(step, *args):
        if step == TINY.chunk_steps:
            stop()
        return real(step, *args)

    monkeypatch.setattr(reporting, "chunk_line", chunk_line)


def test_sigterm_saves_a_checkpoint_and_resume_finishes_the_run(
    straight_run, tmp_path, monkeypatch, tiny_functions
):
    out = tmp_path / "run"
    before = signal.getsignal(signal.SIGTERM)
    _stop_after_first_chunk(monkeypatch, lambda: os.kill(os.getpid(), signal.SIGTERM))
    with pytest.raises(Interrupted) as info:
        train_tiny(out, tiny_functions)
    assert info.value.signum == signal.SIGTERM
    assert signal.getsignal(signal.SIGTERM) == before
    saved = json.loads((out / "run.json").read_text())
    assert saved["status"] == "interrupted" and saved["env_steps_per_agent"] == 40
    assert saved["eval_seed"] == RUN_SEEDS[0]  # the default: the first seed
    assert checkpoint.verify_checksums(out / "checkpoints" / "40")
    partial = np.load(out / "metrics.npz")  # the episodes so far are not lost
    played = partial["outcome"] > 0
    assert played.any() and not played.all()
    assert (out / "episodes.csv").read_text().count("\n") == 1 + played.sum()
    monkeypatch.undo()
    assert train_tiny(out, tiny_functions, resume=True)["status"] == "finished"
    _assert_same_params(out, straight_run)


def test_a_signal_inside_the_donating_chunk_call_still_saves_a_checkpoint(tmp_path, tiny_functions):
    # The chunk donates its input state; a signal landing after the call took it and before
    # the new state came back left nothing to save ("Array has been deleted", H100 run).
    trainer, init_fn, chunk_fn = tiny_functions
    calls = []

    def chunk_then_signal(state, hp, step):
        new = chunk_fn(state, hp, step)  # `state` is donated from here on
        if not calls:
            os.kill(os.getpid(), signal.SIGTERM)
        calls.append(step)
        return new

    out = tmp_path / "run"
    with pytest.raises(Interrupted):
        train_tiny(out, (trainer, init_fn, chunk_then_signal))
    assert len(calls) == 1
    saved = json.loads((out / "run.json").read_text())
    assert saved["status"] == "interrupted" and saved["env_steps_per_agent"] == TINY.chunk_steps
    assert checkpoint.verify_checksums(out / "checkpoints" / str(TINY.chunk_steps))


def test_stop_requests_hold_a_signal_until_checked():
    ran_on = []
    before = signal.getsignal(signal.SIGINT)  # Python's, or SIG_IGN in a background job
    with interrupts.stop_requests() as stop:
        os.kill(os.getpid(), signal.SIGINT)
        ran_on.append(True)  # the signal did not stop the block
        with pytest.raises(Interrupted) as info:
            stop.check()
    assert ran_on == [True] and info.value.signum == signal.SIGINT
    assert signal.getsignal(signal.SIGINT) is before


def test_resume_of_a_run_killed_before_its_first_checkpoint_starts_afresh(
    straight_run, tmp_path, monkeypatch, capsys, tiny_functions
):
    out = tmp_path / "run"

    def die():  # what kill -9 leaves: run.json "running", no checkpoint, no handler ran
        raise SystemExit("killed")

    _stop_after_first_chunk(monkeypatch, die)
    with pytest.raises(SystemExit):
        train_tiny(out, tiny_functions)
    monkeypatch.undo()
    assert json.loads((out / "run.json").read_text())["status"] == "running"
    assert not (out / "checkpoints").exists()
    with pytest.raises(ValueError, match="pass --resume"):
        train_tiny(out, tiny_functions)
    assert train_tiny(out, tiny_functions, resume=True)["status"] == "finished"
    err = " ".join(capsys.readouterr().err.split())  # rich wraps long lines
    assert "has no checkpoint yet (stopped before the first one): starting it afresh" in err
    _assert_same_params(out, straight_run)
    log = [json.loads(x) for x in (out / "train_log.jsonl").read_text().splitlines()]
    assert [line["step"] for line in log] == [40, 80, 120]  # the dead run's line is gone


def test_resume_with_other_agents_names_the_difference(straight_run):
    expected = (
        r"its config or agents differ from these: agents\[4\]\.seed: run.json has 4, "
        r"these options give 5"
    )
    with pytest.raises(ValueError, match=expected):
        run_training(TINY, RUN_HP, {}, [0, 1, 2, 3, 5], straight_run, resume=True, progress=False)


def test_interrupt_is_one_line_without_traceback(monkeypatch, capsys):
    def interrupted(args):
        raise Interrupted(signal.SIGTERM)

    monkeypatch.setattr("advisor_jax.cli.main.train_command", interrupted)
    with pytest.raises(SystemExit) as info:
        cli_main(["train"])
    assert info.value.code == 128 + signal.SIGTERM
    err = capsys.readouterr().err
    assert err.strip() == "stopped by SIGTERM" and "Traceback" not in err


# 4, 6, 7: options are checked before anything runs ------------------------------------


@pytest.mark.parametrize(
    ("argv", "message"),
    [
        (["--eval-arenas", "bogus"], "unknown evaluation arena 'bogus'; choose from"),
        (["--arena", "nowhere"], "unknown arena 'nowhere'"),
        (["--checkpoint-every", "-1"], "checkpoint_every must be >= 0"),
        (["--eval-episodes", "-3"], "eval_episodes must be >= 0"),
        (["--seed", str(2**64)], f"seed {2**64} is out of range: seeds are integers in"),
        (["--seed", "-1"], r"seed -1 is out of range: seeds are integers in \[0, 2\^64 - 1\]"),
        (["--eval-seed", "-2"], r"eval_seed -2 is out of range"),
        (["--seed", str(2**64 - 1), "--seeds", "2"], "runs past the largest seed"),
        (["--hp", "beta=0.1", "beta=0.2"], r"--hp sets beta twice \('beta=0.1' and 'beta=0.2'\)"),
        (["--grid", "tau=0.1,0.2", "tau=0.3"], "--grid sets tau twice"),
        (["--hp", "beta=0.1", "--grid", "beta=0.2,0.3"], "beta given to both --hp and --grid"),
    ],
)
def test_bad_option_is_refused_before_anything_runs(tmp_path, capsys, argv, message):
    out = tmp_path / "run"
    with pytest.raises(SystemExit) as info:
        cli_main(["train", "--preset", "quick", "--out", str(out), *argv])
    assert info.value.code == 2
    err = " ".join(capsys.readouterr().err.split())
    assert "Traceback" not in err
    assert re.search(message, err), err
    assert not out.exists()  # nothing written, nothing compiled


def test_empty_out_is_refused(tmp_path, monkeypatch, capsys):
    monkeypatch.chdir(tmp_path)
    for command in (["train", "--out", ""], ["export", "somewhere", "--out", " "]):
        with pytest.raises(SystemExit) as info:
            cli_main(command)
        assert info.value.code == 2
        assert "--out '' is empty" in capsys.readouterr().err
    assert os.listdir(tmp_path) == []
    with pytest.raises(ValueError, match="must not be empty"):
        run_training(TINY, RUN_HP, {}, RUN_SEEDS, "", progress=False)


def test_seed_keys_do_not_alias_and_keep_the_normal_range():
    for seed in (0, 1, 7, 12345, 2**31 - 1, 2**31, 2**32 - 1):
        np.testing.assert_array_equal(seed_key(seed), jax.random.PRNGKey(seed))
    big = [2**32, 2**40, 2**63, 2**64 - 1]
    keys = {tuple(np.asarray(seed_key(s)).tolist()) for s in [0, *big]}
    assert len(keys) == 5  # 2^40 no longer gives seed 0's key; 2^63 no longer overflows
    np.testing.assert_array_equal(agent_keys([2**40]), [[256, 0]])
    cfg, _, _, seeds, _ = build_run(TrainArgs(seed=2**63, seeds=2))
    assert seeds == [2**63, 2**63 + 1]
    assert cfg.agent.precision == "fp32"  # the default; --precision bf16 reaches the agent
    assert build_run(TrainArgs(precision="bf16"))[0].agent.precision == "bf16"
    with pytest.raises(ValueError, match=r"seed 18446744073709551616 is out of range"):
        seed_key(2**64)


def test_policy_delay_reaches_the_td3_family_only():
    assert build_run(TrainArgs(agent="ATD3+AfDP"))[0].agent.policy_delay == 4  # Table A4
    assert build_run(TrainArgs(agent="ATD3+AfDP", policy_delay=2))[0].agent.delay == 2
    with pytest.raises(ValueError, match=r"--policy-delay 2: ADDPG\+AfP \(algo addpg\)"):
        build_run(TrainArgs(agent="ADDPG+AfP", policy_delay=2))
    with pytest.raises(ValueError, match=r"policy_delay must be a positive integer, got 0"):
        build_run(TrainArgs(agent="ATD3+AfDP", policy_delay=0))


def test_parse_assignments_keeps_distinct_names():
    assert parse_assignments(["beta=0.1", "tau=0.2,0.3"], "--grid") == {
        "beta": [0.1],
        "tau": [0.2, 0.3],
    }
