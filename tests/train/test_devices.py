"""A population sharded over 2 or 3 devices equals the same population on one device.

The TINY population of test_integrity.py (5 agents) is trained by tests/train/devices_worker.py
in subprocesses with 2 and 3 forced CPU devices: 5 agents on 2 devices pads one frozen
agent, on 3 devices one as well (6 = 2 × 3). Each agent's discrete trajectory must be
identical to the one-device run's and its parameters within the bound of
``tests/compare.assert_same_training``; a run checkpointed on 2 devices must resume on 1,
and one checkpointed on 1 device on 3.
"""

from __future__ import annotations

import json
import os
import socket
import subprocess
import sys
from pathlib import Path

import jax
import numpy as np
import pytest

from advisor_jax.training import checkpoint, reporting
from advisor_jax.training.population import agent_keys
from tests.compare import assert_same_agent
from tests.train.conftest import RUN_SEEDS, TINY, agent_slice, train_tiny

WORKER = Path(__file__).with_name("devices_worker.py")


def _worker(devices: int, *runs: tuple[str, Path]) -> None:
    """Runs devices_worker.py: each (mode, out) of ``runs`` in one process on ``devices``."""
    env = {k: v for k, v in os.environ.items() if k != "XLA_FLAGS"}
    done = subprocess.run(
        [sys.executable, str(WORKER), str(devices), *(f"{m}={out}" for m, out in runs)],
        env=env, capture_output=True, text=True, timeout=600,
    )  # fmt: skip
    assert done.returncode == 0, done.stderr[-3000:]


def _final_state(out: Path, abstract):
    state, _ = checkpoint.restore_latest(out / "checkpoints", abstract)
    return jax.device_get(state)


@pytest.fixture(scope="module")
def reference(tiny_functions, straight_run):
    """(initial state, final state) of the one-device run, and the state's abstract."""
    trainer, init_fn, _ = tiny_functions
    keys = agent_keys(RUN_SEEDS)
    abstract = jax.eval_shape(jax.vmap(trainer.init), keys)
    return jax.device_get(init_fn(keys)), _final_state(straight_run, abstract), abstract


def _assert_same_agents(got, reference):
    start, want, _ = reference
    for i in range(len(RUN_SEEDS)):
        got_i, want_i, start_i = (agent_slice(t, i) for t in (got, want, start))
        assert_same_agent(got_i, want_i, start_i, i)
        assert bool(got_i.diverged) == bool(want_i.diverged)


def test_two_devices_equal_one_and_resume_on_one(reference, tmp_path, tiny_functions):
    full, interrupted = tmp_path / "full", tmp_path / "interrupted"
    _worker(2, ("full", full), ("interrupt", interrupted))  # one compile for both runs
    saved = json.loads((full / "run.json").read_text())
    assert saved["status"] == "finished" and saved["devices"] == 2
    assert len(saved["agents"]) == len(RUN_SEEDS)  # the padding agent is never written
    _assert_same_agents(_final_state(full, reference[2]), reference)
    metrics = np.load(full / "metrics.npz")
    assert metrics["outcome"].shape == (len(RUN_SEEDS), TINY.episodes)

    # checkpointed on 2 devices...
    assert json.loads((interrupted / "run.json").read_text())["status"] == "interrupted"
    train_tiny(interrupted, tiny_functions, resume=True)  # ...finished on one
    _assert_same_agents(_final_state(interrupted, reference[2]), reference)


def test_two_processes_equal_one(reference, tmp_path):
    """Two jax.distributed processes on localhost, one CPU device each, train one population
    into one run directory (process 0 writes it): the same per-agent results."""
    with socket.socket() as s:  # a free port for the coordinator
        s.bind(("127.0.0.1", 0))
        port = str(s.getsockname()[1])
    out = tmp_path / "run"
    env = {k: v for k, v in os.environ.items() if k != "XLA_FLAGS"}
    argv = [sys.executable, str(WORKER), "1", f"full={out}"]
    procs = [
        subprocess.Popen([*argv, str(i), port], env=env, stdout=subprocess.PIPE,
                         stderr=subprocess.STDOUT, text=True)
        for i in range(2)
    ]  # fmt: skip
    outputs = [p.communicate(timeout=600)[0] for p in procs]
    for p, text in zip(procs, outputs, strict=True):
        assert p.returncode == 0, text[-3000:]
    saved = json.loads((out / "run.json").read_text())
    assert saved["status"] == "finished" and saved["processes"] == 2 and saved["devices"] == 2
    _assert_same_agents(_final_state(out, reference[2]), reference)


def test_one_device_checkpoint_resumes_on_three(reference, tmp_path, tiny_functions, monkeypatch):
    out = tmp_path / "run"
    real = reporting.chunk_line

    def chunk_line(step, *args):
        if step == TINY.chunk_steps:
            raise KeyboardInterrupt
        return real(step, *args)

    monkeypatch.setattr(reporting, "chunk_line", chunk_line)
    with pytest.raises(KeyboardInterrupt):
        train_tiny(out, tiny_functions)
    monkeypatch.undo()
    _worker(3, ("resume", out))
    saved = json.loads((out / "run.json").read_text())
    assert saved["status"] == "finished" and saved["devices"] == 3
    _assert_same_agents(_final_state(out, reference[2]), reference)
