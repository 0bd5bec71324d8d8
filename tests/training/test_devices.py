"""A population sharded over 2 devices equals the same population on one device.

The TINY population of test_integrity.py (5 agents) is trained by tests/training/devices_worker.py
in subprocesses: one process with 2 forced CPU devices (5 agents pad one frozen agent: 6 =
3 × 2), and two jax.distributed processes of one device each. Each agent's discrete
trajectory must be identical to the one-device run's and its parameters within the bound of
``tests/compare.assert_same_training``; a run checkpointed on 2 devices must resume on 1,
and one checkpointed on 1 device (no padding) on 2 (padded).
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
from tests.training.conftest import RUN_SEEDS, TINY, agent_slice, train_tiny

WORKER = Path(__file__).with_name("devices_worker.py")


def _start(log: Path, devices: int, *runs: tuple[str, Path], process: tuple = ()):
    """Starts devices_worker.py: each (mode, out) of ``runs`` in one process on ``devices``
    (and, with ``process`` = (index, port), as one of two jax.distributed processes)."""
    env = dict(os.environ)  # with the suite's XLA_FLAGS: the worker adds its devices
    argv = [sys.executable, str(WORKER), str(devices), *(f"{m}={out}" for m, out in runs)]
    with log.open("w") as sink:  # a file, not a pipe: a full pipe would block the worker
        return subprocess.Popen([*argv, *map(str, process)], env=env, stdout=sink,
                                stderr=subprocess.STDOUT, text=True)  # fmt: skip


def _wait(*procs: tuple[subprocess.Popen, Path]) -> None:
    for proc, log in procs:
        proc.wait(timeout=600)
        assert proc.returncode == 0, log.read_text()[-3000:]


def _interrupt_after_first_chunk(out: Path, program) -> None:
    """A one-device TINY run into ``out``, stopped (checkpoint saved) after its first chunk."""
    real = reporting.chunk_line

    def chunk_line(step, *args):
        if step == TINY.chunk_steps:
            raise KeyboardInterrupt
        return real(step, *args)

    reporting.chunk_line = chunk_line
    try:
        with pytest.raises(KeyboardInterrupt):
            train_tiny(out, program)
    finally:
        reporting.chunk_line = real


@pytest.fixture(scope="module")
def workers(tmp_path_factory, tiny_functions):
    """Every worker process of this module, started at once so that they share the cores
    while this process waits (XLA's compiles are mostly single-threaded): one process on 2
    devices, whose three runs share one compile (one whole, one interrupted, and the finish
    of a run interrupted on one device), and a whole run by two jax.distributed processes.
    Each test waits for its own."""
    root = tmp_path_factory.mktemp("devices")
    out = {name: root / name for name in ("full", "interrupted", "on_two", "distributed")}
    _interrupt_after_first_chunk(out["on_two"], tiny_functions)
    with socket.socket() as s:  # a free port for the coordinator
        s.bind(("127.0.0.1", 0))
        port = s.getsockname()[1]
    logs = {name: root / f"{name}.log" for name in ("two", "process0", "process1")}
    procs = {
        "two": (_start(logs["two"], 2, ("full", out["full"]), ("interrupt", out["interrupted"]),
                       ("resume", out["on_two"])), logs["two"]),
        **{f"process{i}": (_start(logs[f"process{i}"], 1, ("full", out["distributed"]),
                                  process=(i, port)), logs[f"process{i}"]) for i in range(2)},
    }  # fmt: skip
    yield out, procs
    for proc, _ in procs.values():
        if proc.poll() is None:
            proc.kill()


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


def test_two_devices_equal_one_and_resume_on_one(reference, workers, tiny_functions):
    out, procs = workers
    _wait(procs["two"])  # one compile for its three runs
    full, interrupted = out["full"], out["interrupted"]
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


def test_two_processes_equal_one(reference, workers):
    """Two jax.distributed processes on localhost, one CPU device each, train one population
    into one run directory (process 0 writes it): the same per-agent results."""
    out, procs = workers
    _wait(procs["process0"], procs["process1"])
    saved = json.loads((out["distributed"] / "run.json").read_text())
    assert saved["status"] == "finished" and saved["processes"] == 2 and saved["devices"] == 2
    _assert_same_agents(_final_state(out["distributed"], reference[2]), reference)


def test_one_device_checkpoint_resumes_on_two(reference, workers):
    out, procs = workers
    _wait(procs["two"])
    saved = json.loads((out["on_two"] / "run.json").read_text())
    assert saved["status"] == "finished" and saved["devices"] == 2
    _assert_same_agents(_final_state(out["on_two"], reference[2]), reference)
