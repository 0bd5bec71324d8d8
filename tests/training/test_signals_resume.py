"""Issue 39, classes 1 and 2: where a signal takes effect, and resuming a run that is
finished or finishing.

A signal is noted where it lands and acted on between chunks (``interrupts``): the chunk's
log row, its periodic checkpoint and the checkpoint's checksums are complete before the run
stops, and a second Ctrl-C changes nothing. A finished run is left as it is by ``--resume``;
a run stopped after its training (during the final evaluation) resumes the evaluation,
not the training. Every run is the session's TINY configuration (``conftest``).
"""

from __future__ import annotations

import json
import os
import signal

import jax
import numpy as np
import pytest
from orbax.checkpoint._src.path import deleter

from advisor_jax.agent.advisors import tree_sha256
from advisor_jax.cli.main import main as cli_main
from advisor_jax.evaluation.evaluate import population_evaluator
from advisor_jax.training import checkpoint, host_loop, run_outputs
from advisor_jax.training.run_directory import reevaluate
from advisor_jax.training.runlock import Interrupted
from tests.training.conftest import RUN_HP, RUN_SEEDS, TINY, train_tiny

TIMING = ("seconds", "steps_per_second")
EVAL_EPISODES = 4


def log_rows(out):
    """train_log.jsonl without its timing fields."""
    rows = [json.loads(x) for x in (out / "train_log.jsonl").read_text().splitlines()]
    return [{k: v for k, v in row.items() if k not in TIMING} for row in rows]


def assert_same_metrics(out_a, out_b):
    a, b = np.load(out_a / "metrics.npz"), np.load(out_b / "metrics.npz")
    assert sorted(a.files) == sorted(b.files)
    for name in a.files:
        np.testing.assert_array_equal(a[name], b[name], err_msg=name)


def assert_same_params(out_a, out_b):
    leaves = [jax.tree_util.tree_leaves(checkpoint.load_tree(o / "params")) for o in (out_a, out_b)]
    for x, y in zip(*leaves, strict=True):
        np.testing.assert_array_equal(x, y)


def signal_in_chunk(program, signum, on_call=0):
    """``program`` whose chunk sends ``signum`` to this process inside its ``on_call``-th call,
    after the call took (donated) its state: the step counter then moves before the row is
    written."""
    trainer, init_fn, chunk_fn = program
    calls = []

    def chunk(state, hp, step):
        new = chunk_fn(state, hp, step)
        if len(calls) == on_call:
            os.kill(os.getpid(), signum)
        calls.append(int(step))
        return new

    return trainer, init_fn, chunk


def assert_checkpoints_whole(out):
    """Every kept checkpoint has its checksums (with this run's identity) and verifies; no
    orbax temporary directory is left."""
    identity = json.loads((out / "run.json").read_text())["identity"]
    ckpts = out / "checkpoints"
    steps = [p for p in ckpts.iterdir() if p.name.isdigit()]
    assert steps, os.listdir(ckpts)
    for step in steps:
        assert checkpoint.verify_checksums(step, identity), step
    assert not [p for p in ckpts.iterdir() if not p.name.isdigit()], os.listdir(ckpts)


# Class 1: a held-back signal lands where the run is consistent -------------------------


def test_sigterm_inside_a_chunk_then_resume_gives_every_log_row(
    straight_run, tmp_path, capsys, tiny_functions
):
    """... and the same networks by ``agent_params_sha256``, where ``params_sha256`` (the
    stored files) differs; a resume under other ``XLA_FLAGS`` than the start's says so."""
    out = tmp_path / "run"
    with pytest.raises(Interrupted) as info:
        train_tiny(out, signal_in_chunk(tiny_functions, signal.SIGTERM))
    assert info.value.signum == signal.SIGTERM
    assert [row["step"] for row in log_rows(out)] == [TINY.chunk_steps]  # the row of the stop
    record = json.loads((out / "run.json").read_text())
    assert record["jax"] == jax.__version__
    assert record["xla_flags"] == os.environ.get("XLA_FLAGS", "")
    (out / "run.json").write_text(json.dumps({**record, "xla_flags": "--xla_started_with=1"}))
    capsys.readouterr()
    train_tiny(out, tiny_functions, resume=True)
    err = " ".join(capsys.readouterr().err.split())
    assert f"warning: XLA_FLAGS '--xla_started_with=1' → {record['xla_flags']!r} since" in err
    assert log_rows(out) == log_rows(straight_run)
    assert_same_metrics(out, straight_run)
    assert_same_params(out, straight_run)
    resumed, straight = (json.loads((o / "run.json").read_text()) for o in (out, straight_run))
    assert resumed["agent_params_sha256"] == straight["agent_params_sha256"]
    assert resumed["params_sha256"] != straight["params_sha256"]
    networks = checkpoint.load_tree(out / "params")
    assert resumed["agent_params_sha256"] == [
        tree_sha256(jax.tree.map(lambda leaf: leaf[i], networks))  # noqa: B023
        for i in range(len(RUN_SEEDS))
    ]
    assert len(set(resumed["agent_params_sha256"])) == len(RUN_SEEDS)


def _second_sigint_while_checksums_are_recorded(monkeypatch):
    real = checkpoint.record_checksums

    def record(directory, run=None):
        os.kill(os.getpid(), signal.SIGINT)  # lands between orbax's commit and the manifest
        return real(directory, run)

    monkeypatch.setattr(checkpoint, "record_checksums", record)


def _sigint_while_an_old_checkpoint_is_deleted(monkeypatch):
    real = deleter.PathDeleter.delete

    def delete(self, path, **kw):
        files = [os.path.join(d, f) for d, _, names in os.walk(str(path)) for f in names]
        os.unlink(sorted(files)[0])  # the step is half deleted when the signal lands
        os.kill(os.getpid(), signal.SIGINT)
        return real(self, path, **kw)

    monkeypatch.setattr(deleter.PathDeleter, "delete", delete)


@pytest.mark.parametrize(
    ("first_in_chunk", "patch"),
    [
        (True, _second_sigint_while_checksums_are_recorded),  # Ctrl-C twice
        (False, _sigint_while_an_old_checkpoint_is_deleted),  # the third save deletes step 40
    ],
    ids=["second-ctrl-c-in-the-interrupt-save", "ctrl-c-while-orbax-deletes"],
)
def test_signals_during_saves_leave_every_checkpoint_whole(
    straight_run, tmp_path, monkeypatch, tiny_functions, first_in_chunk, patch
):
    out = tmp_path / "run"
    program = signal_in_chunk(tiny_functions, signal.SIGINT) if first_in_chunk else tiny_functions
    patch(monkeypatch)
    with pytest.raises(Interrupted) as info:
        train_tiny(out, program, checkpoint_every=1)
    monkeypatch.undo()
    assert info.value.signum == signal.SIGINT and "continue with --resume" in info.value.detail
    assert json.loads((out / "run.json").read_text())["status"] == "interrupted"
    assert_checkpoints_whole(out)
    assert train_tiny(out, tiny_functions, resume=True)["status"] == "finished"
    assert log_rows(out) == log_rows(straight_run)
    assert_same_params(out, straight_run)


def test_two_ctrl_c_give_one_clear_line(tmp_path, monkeypatch, capsys, tiny_functions):
    out = tmp_path / "run"
    real = host_loop.run_training
    program = signal_in_chunk(tiny_functions, signal.SIGINT)

    def tiny_run(cfg, base_hp, grid, seeds, out_dir, **kw):  # the CLI's options, TINY's run
        return real(TINY, RUN_HP, {}, RUN_SEEDS, out_dir, program=program, progress=False,
                    eval_episodes=0, checkpoint_every=0)  # fmt: skip

    monkeypatch.setattr(host_loop, "run_training", tiny_run)
    _second_sigint_while_checksums_are_recorded(monkeypatch)
    with pytest.raises(SystemExit) as info:
        cli_main(["train", "--out", str(out), "--no-progress"])
    assert info.value.code == 128 + signal.SIGINT
    err = capsys.readouterr().err
    assert "Traceback" not in err
    stopped = [line for line in err.splitlines() if line.startswith("stopped by")]
    assert stopped == [
        f"stopped by SIGINT at environment step {TINY.chunk_steps}: checkpoint saved; continue "
        f"with --resume (--out {out})"
    ]
    others = [line for line in err.splitlines() if line and line not in stopped]
    assert len(others) <= 1 and all(line.startswith("SIGINT: stopping after") for line in others)
    assert json.loads((out / "run.json").read_text())["status"] == "interrupted"
    assert_checkpoints_whole(out)


def test_sighup_is_a_stop_request_unless_ignored():
    from advisor_jax.training import interrupts

    before = signal.getsignal(signal.SIGHUP)
    with interrupts.stop_requests() as stop:
        os.kill(os.getpid(), signal.SIGHUP)  # a closed terminal: a checkpoint, not a death
        assert stop.requested and stop.signum == signal.SIGHUP
    assert signal.getsignal(signal.SIGHUP) is before
    signal.signal(signal.SIGHUP, signal.SIG_IGN)  # started under nohup: it stays ignored
    try:
        with interrupts.stop_requests() as stop:
            assert signal.getsignal(signal.SIGHUP) is signal.SIG_IGN
            os.kill(os.getpid(), signal.SIGHUP)
            assert not stop.requested
    finally:
        signal.signal(signal.SIGHUP, before)


# Class 2: resuming a run that is finished, or finishing --------------------------------


def with_step_bound(program, max_steps=10 * TINY.episodes * TINY.max_episode_steps):
    """``program`` with a looser step bound: its agents finish before it, as in most runs
    (``max_steps`` bounds the longest possible run), so a resumed finished run could train
    another chunk."""
    trainer, init_fn, chunk_fn = program
    return trainer._replace(max_steps=max_steps), init_fn, chunk_fn


def _snapshot(directory):
    """Every file below ``directory``: (bytes, mtime) by relative name."""
    return {
        p.relative_to(directory).as_posix(): (p.read_bytes(), p.stat().st_mtime_ns)
        for p in sorted(directory.rglob("*"))
        if p.is_file() and p.name != ".lock"
    }


def test_resume_of_a_finished_run_says_so_and_changes_nothing(
    straight_run, tmp_path, capsys, tiny_functions
):
    import shutil

    out = tmp_path / "run"
    shutil.copytree(straight_run, out)
    before = _snapshot(out)
    summary = train_tiny(out, with_step_bound(tiny_functions), resume=True)
    assert summary["status"] == "finished"
    assert _snapshot(out) == before  # no extra chunk, no rewritten results
    err = " ".join(capsys.readouterr().err.split())
    assert f"{out} is a finished run: nothing to resume" in err


def test_drop_checkpoints_deletes_them_once_the_run_is_finished_and_keeps_the_results(
    straight_run, tmp_path, capsys, tiny_functions
):
    import shutil

    out = tmp_path / "run"  # trained with them dropped: the same results, no checkpoints/
    train_tiny(out, with_step_bound(tiny_functions), drop_checkpoints=True)
    assert not (out / "checkpoints").exists() and (straight_run / "checkpoints").is_dir()
    assert_same_params(out, straight_run)
    assert_same_metrics(out, straight_run)
    assert "removed" in capsys.readouterr().err

    kept = tmp_path / "kept"  # a finished run resumed with the option: only checkpoints/ goes
    shutil.copytree(straight_run, kept)
    before = {k: v for k, v in _snapshot(kept).items() if not k.startswith("checkpoints/")}
    train_tiny(kept, with_step_bound(tiny_functions), resume=True, drop_checkpoints=True)
    assert _snapshot(kept) == before

    summary = json.loads((kept / "run.json").read_text())  # not finished: kept
    (kept / "checkpoints").mkdir()
    host_loop.drop_finished_checkpoints(kept, {**summary, "status": "interrupted"}, None)
    assert (kept / "checkpoints").is_dir()


@pytest.fixture(scope="module")
def tiny_evaluators():
    return {
        "training": population_evaluator(
            "training", EVAL_EPISODES, TINY.agent.actor_hidden, TINY.max_episode_steps
        )
    }


@pytest.mark.parametrize("how", ["sigint", "kill"])
def test_stopped_during_the_final_evaluation_resume_evaluates_without_training(
    straight_run, tmp_path, monkeypatch, capsys, tiny_functions, tiny_evaluators, how
):
    out = tmp_path / "run"
    real = run_outputs.evaluate_population

    def evaluate(*args, **kw):
        if how == "kill":  # what kill -9 leaves: no handler runs, run.json says "running"
            raise SystemExit("killed")
        os.kill(os.getpid(), signal.SIGINT)
        return real(*args, **kw)

    def compiled_once(*args, **kw):  # the run's evaluator, compiled once for these tests
        return tiny_evaluators["training"]

    monkeypatch.setattr(run_outputs, "population_evaluator", compiled_once)
    monkeypatch.setattr(run_outputs, "evaluate_population", evaluate)
    kw = {"eval_episodes": EVAL_EPISODES, "eval_arenas": ("training",)}
    program = with_step_bound(tiny_functions)
    with pytest.raises(Interrupted if how == "sigint" else SystemExit) as info:
        train_tiny(out, program, **kw)
    monkeypatch.setattr(run_outputs, "evaluate_population", real)
    status = json.loads((out / "run.json").read_text())["status"]
    assert status == ("interrupted" if how == "sigint" else "running")
    if how == "sigint":
        assert "during the final evaluation" in info.value.detail
    trained = log_rows(out)
    assert trained == log_rows(straight_run)
    summary = train_tiny(out, program, resume=True, **kw)
    assert summary["status"] == "finished"
    assert log_rows(out) == trained  # the evaluation resumed, not the training
    assert_same_params(out, straight_run)
    assert_same_metrics(out, straight_run)
    again = reevaluate(out, RUN_SEEDS[0], EVAL_EPISODES, ("training",), tiny_evaluators)
    assert json.loads((out / "eval.json").read_text()) == json.loads(json.dumps(again))
    err = " ".join(capsys.readouterr().err.split())
    assert "finished its training before it stopped: finishing it" in err
