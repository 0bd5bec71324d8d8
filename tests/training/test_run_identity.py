"""Issue 39, class 3: files tied to the run they belong to.

run.json, every checkpoint's and the final parameters' sha256.json record the run's
identity (``run_state.run_identity``: the sha256 of its config and agents, and its seeds),
and run.json the sha256 of params/sha256.json. A directory that is not exactly one run is
refused: another run's params/ or checkpoint, a killed run's leftovers under a new run, a
deleted checksum file, a run.json edited to another seed. Also: ``export --sign-key``.
"""

from __future__ import annotations

import json
import os
import shutil
import signal

import numpy as np
import pytest

from advisor_jax.cli.main import main as cli_main
from advisor_jax.training import checkpoint, reporting, run_state
from advisor_jax.training.run_directory import load_actor
from advisor_jax.training.runlock import Interrupted
from tests.training.conftest import RUN_SEEDS, TINY, train_tiny
from tests.training.test_signals_resume import assert_same_params, signal_in_chunk

OTHER_SEEDS = [5, 6, 7, 8, 9]


def train_other(out, program, **kw):
    """A TINY run of OTHER_SEEDS: another run of the same shapes (no new compile)."""
    return train_tiny(out, program, seeds=OTHER_SEEDS, **kw)


@pytest.fixture(scope="module")
def other_run(tmp_path_factory, tiny_functions):
    out = tmp_path_factory.mktemp("other")
    train_other(out, tiny_functions)
    return out


def snapshot(directory):
    return {
        p.relative_to(directory).as_posix(): p.read_bytes()
        for p in sorted(directory.rglob("*"))
        if p.is_file() and p.name != ".lock"
    }


def assert_export_and_evaluate_refuse(out, tmp_path, capsys, message):
    """``export`` and ``evaluate RUN:0`` both exit 2 with one line matching ``message``, and
    no export directory appears."""
    commands = (
        ["export", str(out), "--out", str(tmp_path / "policy")],
        ["evaluate", "--policy", f"{out}:0", "--episodes", "2"],
    )
    for command in commands:
        with pytest.raises(SystemExit) as info:
            cli_main(command)
        assert info.value.code == 2
        err = capsys.readouterr().err.strip().splitlines()
        assert len(err) == 1 and err[0].startswith("error: ") and message in err[0], err
    assert not (tmp_path / "policy").exists()


def test_a_new_run_into_a_killed_runs_directory_is_refused(tmp_path, monkeypatch, tiny_functions):
    out = tmp_path / "run"
    real = reporting.chunk_line

    def die_after_the_second_chunk(step, *args):
        if step == 2 * TINY.chunk_steps:  # step 40 is checkpointed: a kill -9 after it
            raise SystemExit("killed")
        return real(step, *args)

    monkeypatch.setattr(reporting, "chunk_line", die_after_the_second_chunk)
    with pytest.raises(SystemExit):
        train_tiny(out, tiny_functions, checkpoint_every=1)
    monkeypatch.undo()
    (out / "run.json").unlink()
    (out / "train_log.jsonl").unlink()
    before = snapshot(out)
    with pytest.raises(ValueError, match=r"is not empty \(checkpoints\) and holds no run.json"):
        train_other(out, tiny_functions)
    assert snapshot(out) == before  # nothing mixed in


def _params_of_another_run(out, other_run):
    shutil.rmtree(out / "params")
    shutil.copytree(other_run / "params", out / "params")


def _params_checksums_deleted(out, other_run):
    (out / "params" / checkpoint.CHECKSUMS).unlink()


@pytest.mark.parametrize(
    ("damage", "message", "line"),
    [
        (
            _params_of_another_run,
            r"not this run's: .*belongs to another run \(seeds \[5,",
            "belongs to another run",
        ),
        (
            _params_checksums_deleted,
            r"sha256.json is missing: this run records checksums",
            "sha256.json is missing",
        ),
    ],
    ids=["params-of-another-run", "params-checksums-deleted"],
)
def test_params_not_of_this_run_are_refused(
    straight_run, other_run, tmp_path, capsys, damage, message, line
):
    out = tmp_path / "run"
    shutil.copytree(straight_run, out)
    damage(out, other_run)
    with pytest.raises(ValueError, match=message):
        load_actor(out, 0)
    assert_export_and_evaluate_refuse(out, tmp_path, capsys, line)


def test_run_json_edited_to_another_seed_is_refused(straight_run, tmp_path, capsys):
    out = tmp_path / "run"
    shutil.copytree(straight_run, out)
    record = json.loads((out / "run.json").read_text())
    record["agents"][0]["seed"] = 9  # export would label seed 0's weights as seed 9's
    (out / "run.json").write_text(json.dumps(record))
    assert_export_and_evaluate_refuse(out, tmp_path, capsys, "does not match its own config")


def test_a_checkpoint_of_another_run_is_refused_on_resume(tmp_path, tiny_functions):
    ours, theirs = tmp_path / "ours", tmp_path / "theirs"
    with pytest.raises(Interrupted):
        train_tiny(ours, signal_in_chunk(tiny_functions, signal.SIGTERM))
    with pytest.raises(Interrupted):
        train_other(theirs, signal_in_chunk(tiny_functions, signal.SIGTERM))
    step = str(TINY.chunk_steps)
    shutil.rmtree(ours / "checkpoints" / step)
    shutil.copytree(theirs / "checkpoints" / step, ours / "checkpoints" / step)
    before = snapshot(ours)
    with pytest.raises(ValueError, match=r"belongs to another run \(seeds \[5,"):
        train_tiny(ours, tiny_functions, resume=True)
    assert snapshot(ours) == before


def test_a_checkpoint_without_its_checksums_is_set_aside_on_resume(
    straight_run, tmp_path, capsys, tiny_functions
):
    out = tmp_path / "run"
    with pytest.raises(Interrupted):  # checkpoints at steps 40 and 80
        train_tiny(out, signal_in_chunk(tiny_functions, signal.SIGTERM, on_call=1),
                   checkpoint_every=1)  # fmt: skip
    newest = out / "checkpoints" / str(2 * TINY.chunk_steps)
    (newest / checkpoint.CHECKSUMS).unlink()  # a save killed between orbax and its manifest
    assert train_tiny(out, tiny_functions, resume=True)["status"] == "finished"
    err = " ".join(capsys.readouterr().err.split())
    assert f"checkpoint at step {2 * TINY.chunk_steps} is corrupt" in err
    assert f"resuming {out} at environment step {TINY.chunk_steps}" in err
    assert (out / "checkpoints" / f"{2 * TINY.chunk_steps}.corrupt").is_dir()
    assert_same_params(out, straight_run)


def test_a_save_never_skips_over_another_runs_step(other_run, tmp_path, tiny_functions):
    from advisor_jax.training.run_state import run_identity

    ours = json.loads((other_run / "run.json").read_text())["identity"]
    theirs = run_identity({"another": "config"}, [{"seed": 0}])
    ckpts = tmp_path / "checkpoints"
    state = {"x": np.arange(4.0)}
    checkpoint.save_step(ckpts, 40, state, run=theirs)
    with pytest.raises(checkpoint.ForeignRunError, match="belongs to another run"):
        checkpoint.save_step(ckpts, 40, state, run=ours)
    checkpoint.save_step(ckpts, 40, state, run=theirs)  # its own step: kept, as before


def test_export_signs_with_sign_key(straight_run, tmp_path, capsys):
    """The command-line side of signed exports; every file's changed byte is refused in
    tests/runner/test_car_safety.py."""
    from advisor_jax.runner.errors import PolicyError
    from advisor_jax.runner.policy import load_policy

    key_file = tmp_path / "car.key"
    key_file.write_bytes(os.urandom(32))
    key = key_file.read_bytes().strip()
    policy = tmp_path / "policy"
    cli_main(["export", str(straight_run), "--out", str(policy), "--sign-key", str(key_file)])
    assert "signed" in capsys.readouterr().out
    assert load_policy(policy, verify_key=key).meta["config"]["seed"] == RUN_SEEDS[0]
    text = (policy / "policy.json").read_text()
    (policy / "policy.json").write_text(text.replace('"seed": 0', '"seed": 1'))
    with pytest.raises(PolicyError, match="the signature does not match policy.json"):
        load_policy(policy, verify_key=key)


def test_compiled_by_names_each_change_and_skips_what_an_older_run_did_not_record():
    now = {"device": "NVIDIA H100 80GB HBM3", "jax": "0.11.2", "xla_flags": ""}
    assert run_state.compiled_by(now, now) == []
    started = {
        "device": "NVIDIA H200",
        "jax": "0.11.2",
        "xla_flags": "--xla_gpu_deterministic_ops=true",
    }
    assert run_state.compiled_by(started, now) == [
        "device 'NVIDIA H200' → 'NVIDIA H100 80GB HBM3'",
        "XLA_FLAGS '--xla_gpu_deterministic_ops=true' → ''",
    ]
    assert run_state.compiled_by({"device": "NVIDIA H100 80GB HBM3"}, now) == []  # before jax
