"""Issue 39, class 5 (training side): files opened through links, or over files a run did
not write. A run writes its files atomically or appends to its own log, never through a
symbolic or hard link it did not make; a new run takes only an empty directory."""

from __future__ import annotations

import os
import shutil
import signal

import numpy as np
import pytest

from advisor_jax.training import checkpoint, runlock
from advisor_jax.training.runlock import Interrupted
from tests.training.conftest import train_tiny
from tests.training.test_signals_resume import signal_in_chunk

OUTSIDE = "precious data outside the run directory\n"


@pytest.fixture
def outside(tmp_path):
    path = tmp_path / "elsewhere" / "precious.txt"
    path.parent.mkdir()
    path.write_text(OUTSIDE)
    return path


@pytest.mark.parametrize("kind", ["symlink", "hardlink", "fifo"])
def test_a_lock_file_that_is_not_the_runs_own_is_refused(tmp_path, outside, kind, tiny_functions):
    out = tmp_path / "run"
    out.mkdir()
    lock = out / runlock.LOCK_FILE
    if kind == "symlink":
        lock.symlink_to(outside)
        message = "is a symbolic link"
    elif kind == "hardlink":
        os.link(outside, lock)
        message = "has 2 names"
    else:
        os.mkfifo(lock)
        message = "is not a regular file"
    with pytest.raises(OSError, match=message):
        train_tiny(out, tiny_functions)
    assert outside.read_text() == OUTSIDE
    assert sorted(os.listdir(out)) == [runlock.LOCK_FILE]


def test_a_new_run_never_appends_to_a_log_it_did_not_make(tmp_path, outside, tiny_functions):
    out = tmp_path / "run"
    out.mkdir()
    (out / "train_log.jsonl").symlink_to(outside)
    with pytest.raises(ValueError, match=r"is not empty \(train_log.jsonl\)"):
        train_tiny(out, tiny_functions)
    assert outside.read_text() == OUTSIDE


@pytest.mark.parametrize("make", ["symlink", "hardlink"])
def test_the_log_is_appended_only_when_it_is_the_runs_own_file(tmp_path, outside, make):
    from advisor_jax.fileio import append_line

    log = tmp_path / "train_log.jsonl"
    (log.symlink_to if make == "symlink" else lambda p: os.link(p, log))(outside)
    with pytest.raises(OSError, match="symbolic link" if make == "symlink" else "has 2 names"):
        append_line(log, '{"step": 40}')
    assert outside.read_text() == OUTSIDE
    own = tmp_path / "own.jsonl"
    append_line(own, "a")
    append_line(own, "b")
    assert own.read_text() == "a\nb\n"


@pytest.mark.parametrize("entry", ["checkpoints", "train_log.jsonl"])
def test_resume_refuses_a_run_file_that_is_a_link(tmp_path, entry, tiny_functions):
    out = tmp_path / "run"
    with pytest.raises(Interrupted):
        train_tiny(out, signal_in_chunk(tiny_functions, signal.SIGTERM))
    elsewhere = tmp_path / "elsewhere"
    shutil.move(out / entry, elsewhere)
    (out / entry).symlink_to(elsewhere)
    before = sorted(p.name for p in elsewhere.iterdir()) if elsewhere.is_dir() else None
    content = elsewhere.read_bytes() if elsewhere.is_file() else None
    with pytest.raises(ValueError, match=f"{entry} is a symbolic link; a run never writes"):
        train_tiny(out, tiny_functions, resume=True)
    if before is not None:
        assert sorted(p.name for p in elsewhere.iterdir()) == before
    else:
        assert elsewhere.read_bytes() == content


def test_final_parameters_are_never_saved_through_a_left_link(tmp_path):
    elsewhere = tmp_path / "elsewhere"
    elsewhere.mkdir()
    (elsewhere / "keep.txt").write_text(OUTSIDE)
    params = tmp_path / "run" / "params"
    params.parent.mkdir()
    params.with_name("params.partial").symlink_to(elsewhere, target_is_directory=True)
    checkpoint.save_tree(params, {"w": np.arange(3.0)})
    assert sorted(os.listdir(elsewhere)) == ["keep.txt"]
    assert (elsewhere / "keep.txt").read_text() == OUTSIDE
    np.testing.assert_array_equal(checkpoint.load_tree(params)["w"], np.arange(3.0))


def test_arena_xml_never_overwrites_a_file(tmp_path, capsys):
    from advisor_jax.cli.main import main as cli_main

    target = tmp_path / "training.xml"
    target.write_text(OUTSIDE)
    with pytest.raises(SystemExit) as info:
        cli_main(["arena", "training", "--xml", str(target)])
    assert info.value.code == 2
    assert "training.xml exists already; it is never overwritten" in capsys.readouterr().err
    assert target.read_text() == OUTSIDE and os.listdir(tmp_path) == ["training.xml"]
