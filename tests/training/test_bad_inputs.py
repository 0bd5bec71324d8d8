"""Issue 39, class 4: inputs that reached a traceback. Each is one line now, naming the file
or the option and the limit, and nothing is written before an option is refused."""

from __future__ import annotations

import contextlib
import json
import re
import resource
import shutil
import signal

import jax
import pytest

from advisor_jax.cli.main import main as cli_main
from advisor_jax.fileio import atomic_write_bytes
from advisor_jax.training import checkpoint, host_loop
from advisor_jax.training.run_directory import reevaluate
from advisor_jax.training.runlock import Interrupted
from tests.training.conftest import RUN_HP, RUN_SEEDS, TINY, train_tiny
from tests.training.test_signals_resume import log_rows, signal_in_chunk


def one_error_line(capsys) -> str:
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and err[0].startswith("error: "), err
    return err[0]


# run.json that is not a run record: resume, export, evaluate, reevaluate --------------


def _edit(field, value):
    return lambda record: {**record, field: value}


RUN_JSON_CASES = {
    "list": b"[1, 2, 3]",
    "null": b"null",
    "string": b'"a run"',
    "empty-object": b"{}",
    "config-number": _edit("config", 5),
    "agents-string": _edit("agents", "0,1"),
    "agent-number": _edit("agents", [5]),
    "agent-without-seed": _edit("agents", [{"index": 0}]),
    "status-number": _edit("status", 7),
    "diverged-string": _edit("diverged", "all"),
    "nested-too-deep": b"[" * 100_000 + b"]" * 100_000,
    "not-utf8": b"\xff\xfe\x00run",
}


@pytest.mark.parametrize("case", list(RUN_JSON_CASES))
def test_a_run_json_that_is_not_a_run_record_is_one_line(
    straight_run, tmp_path, capsys, tiny_functions, case
):
    out = tmp_path / "run"
    shutil.copytree(straight_run, out)
    content = RUN_JSON_CASES[case]
    if callable(content):
        content = json.dumps(content(json.loads((out / "run.json").read_text()))).encode()
    (out / "run.json").write_bytes(content)
    with pytest.raises(ValueError, match="run.json"):
        train_tiny(out, tiny_functions, resume=True)
    with pytest.raises(ValueError, match="run.json"):
        reevaluate(out, 0, 2)
    for command in (
        ["export", str(out), "--out", str(tmp_path / "policy")],
        ["evaluate", "--policy", f"{out}:0", "--episodes", "2"],
    ):
        with pytest.raises(SystemExit) as info:
            cli_main(command)
        assert info.value.code == 2
        assert "run.json" in one_error_line(capsys)
    assert not (tmp_path / "policy").exists()


# Sizes and repeated values: refused before anything is written -------------------------


@pytest.mark.parametrize(
    ("argv", "message"),
    [
        (["--episodes", "1000000000000"], "--episodes 1,000,000,000,000 is above the limit of"),
        (["--episodes", "2147483648"], "--episodes 2,147,483,648 is above the limit of 10,000,000"),
        (["--seeds", "1000000000000"], "the population 1,000,000,000,000 is above the limit"),
        (["--seeds", "40000", "--grid", "beta=0.1,0.2"], "the population 80,000 is above"),
        (["--eval-episodes", "1000000000"], "--eval-episodes 1,000,000,000 is above the limit"),
        (["--max-episode-steps", "2000000000"], r"above the limit of 2,147,483,647 \(2\^31 - 1"),
        (["--chunk-steps", "2147483000"], r"above the limit of 2,147,483,647 \(2\^31 - 1"),
        (["--buffer-size", str(2**40)], r"the training state of 1 agents needs [\d,.]+ GiB"),
        (["--envs-per-agent", str(2**31)], r"the training state of 1 agents needs"),
        (["--grid", "beta=0.1,0.1"], r"lists 0.1 more than once: .*identical agents"),
        (["--grid", "beta=0.1,1e-1,0.2"], r"lists 0.1 more than once"),
        (["--eval-arenas", "training", "training"], "an evaluation arena is named twice"),
    ],
)
def test_absurd_sizes_and_repeats_are_refused_before_anything_is_written(
    tmp_path, capsys, argv, message
):
    out = tmp_path / "run"
    with pytest.raises(SystemExit) as info:
        cli_main(["train", "--preset", "quick", "--out", str(out), *argv])
    assert info.value.code == 2
    assert re.search(message, one_error_line(capsys))
    assert not out.exists()


@pytest.mark.parametrize(
    "argv",
    [
        ["evaluate", "--episodes", "1000000000"],
        ["export", "nowhere", "--out", "p", "--golden-envs", "100000", "--golden-steps", "100000"],
    ],
)
def test_absurd_evaluation_sizes_are_refused(tmp_path, monkeypatch, capsys, argv):
    monkeypatch.chdir(tmp_path)
    with pytest.raises(SystemExit) as info:
        cli_main(argv)
    assert info.value.code == 2
    assert "is above the limit of 1,000,000" in one_error_line(capsys)
    assert list(tmp_path.iterdir()) == []


@pytest.mark.parametrize("share", [None, "0.5"])
def test_out_of_device_memory_is_one_line(monkeypatch, capsys, share):
    def exhausted(args):
        raise jax.errors.JaxRuntimeError("RESOURCE_EXHAUSTED: Out of memory allocating 80 GiB")

    monkeypatch.setattr("advisor_jax.cli.main.train_command", exhausted)
    if share is None:
        monkeypatch.delenv("XLA_PYTHON_CLIENT_MEM_FRACTION", raising=False)
    else:
        monkeypatch.setenv("XLA_PYTHON_CLIENT_MEM_FRACTION", share)
    with pytest.raises(SystemExit) as info:
        cli_main(["train"])
    assert info.value.code == 2
    line = one_error_line(capsys)
    assert "the device ran out of memory (RESOURCE_EXHAUSTED" in line
    # JAX's default share: how to raise it; a share the user chose: left alone
    assert ("XLA_PYTHON_CLIENT_MEM_FRACTION=0.95" in line) == (share is None)


def test_out_that_is_a_file_is_named(tmp_path, capsys, tiny_functions):
    out = tmp_path / "run"
    out.write_text("notes")
    with pytest.raises(OSError, match=f"--out {out} exists and is not a directory"):
        train_tiny(out, tiny_functions)
    assert out.read_text() == "notes"


# A full disk: one line naming the file --------------------------------------------------


@contextlib.contextmanager
def file_size_limit():
    """Writes past 100 KB fail (EFBIG), as on a full disk (ENOSPC): the same failed write.
    SIGXFSZ, which would kill the process, is ignored as a full disk raises no signal."""
    soft, hard = resource.getrlimit(resource.RLIMIT_FSIZE)
    previous = signal.signal(signal.SIGXFSZ, signal.SIG_IGN)
    resource.setrlimit(resource.RLIMIT_FSIZE, (100_000, hard))
    try:
        yield
    finally:
        resource.setrlimit(resource.RLIMIT_FSIZE, (soft, hard))
        signal.signal(signal.SIGXFSZ, previous)


def test_a_full_disk_during_a_checkpoint_is_one_line(tmp_path, monkeypatch, capsys, tiny_functions):
    out = tmp_path / "run"
    real = host_loop.run_training

    def tiny_run(cfg, base_hp, grid, seeds, out_dir, **kw):  # the CLI's options, TINY's run
        return real(TINY, RUN_HP, {}, RUN_SEEDS, out_dir, program=tiny_functions, progress=False,
                    eval_episodes=0, checkpoint_every=1)  # fmt: skip

    monkeypatch.setattr(host_loop, "run_training", tiny_run)
    with pytest.raises(SystemExit) as info:
        with file_size_limit():
            cli_main(["train", "--out", str(out), "--no-progress"])
    assert info.value.code == 2
    err = capsys.readouterr().err
    assert err.strip() == (
        f"error: cannot save {out.absolute()}/checkpoints/{TINY.chunk_steps}: File too large"
    ), err
    assert [p.name for p in (out / "checkpoints").iterdir()] == []  # no half-written step


def test_a_full_disk_names_the_file_it_could_not_write(tmp_path):
    target = tmp_path / "metrics.npz"
    with file_size_limit():
        with pytest.raises(OSError, match=f"cannot write {target}: File too large"):
            atomic_write_bytes(target, b"x" * 200_000)
    assert list(tmp_path.iterdir()) == []  # the temporary file is gone too


# Damaged files a run reads back ---------------------------------------------------------


def test_resume_drops_log_lines_that_are_not_rows_of_this_run(
    straight_run, tmp_path, tiny_functions
):
    out = tmp_path / "run"
    with pytest.raises(Interrupted):
        train_tiny(out, signal_in_chunk(tiny_functions, signal.SIGTERM))
    junk = [
        "null",
        "[1]",
        json.dumps({"step": TINY.chunk_steps, "per_agent": {"loss/critic": [1.0]}}),  # 1 agent
        "[" * 100_000 + "]" * 100_000,
    ]
    with open(out / "train_log.jsonl", "a") as f:
        f.write("\n".join(junk) + "\n")
    assert train_tiny(out, tiny_functions, resume=True)["status"] == "finished"
    assert log_rows(out) == log_rows(straight_run)


def test_a_checksum_file_nested_too_deeply_is_one_line(straight_run, tmp_path):
    params = tmp_path / "params"
    shutil.copytree(straight_run / "params", params)
    (params / checkpoint.CHECKSUMS).write_text("[" * 100_000 + "]" * 100_000)
    with pytest.raises(ValueError, match=r"sha256.json is corrupt \(RecursionError"):
        checkpoint.load_tree(params)


def test_a_checksum_file_naming_a_file_outside_its_directory_is_refused(straight_run, tmp_path):
    import hashlib

    params = tmp_path / "params"
    shutil.copytree(straight_run / "params", params)
    outside = tmp_path / "outside.txt"
    outside.write_text("not a parameter")
    manifest = json.loads((params / checkpoint.CHECKSUMS).read_text())
    manifest["files"]["../outside.txt"] = hashlib.sha256(outside.read_bytes()).hexdigest()
    (params / checkpoint.CHECKSUMS).write_text(json.dumps(manifest))
    with pytest.raises(ValueError, match=r"it names '../outside.txt', outside"):
        checkpoint.load_tree(params)
