"""A tiny study trained for real on the CPU: its worker killed mid-population, the sweep run
again (it resumes the piece from its checkpoint), then the report. The two processes share
one compiled program through JAX's persistent compilation cache."""

from __future__ import annotations

import json
import os
import signal
import subprocess
import sys
import textwrap
import time
from pathlib import Path

import pytest

from advisor_jax.cli.main import main

ROOT = Path(__file__).resolve().parents[2]
STUDY = """
[study]
name = "tiny"
preset = "quick"
agents = ["ADDPG+AfD"]
seeds = 2
eval_seed = 0
eval_episodes = 2
checkpoint_every = 1

[static]
episodes = 20
max_episode_steps = 30
chunk_steps = 20
batch_size = 32
buffer_size = 512

[grid]
advisor_episodes = [0, "0.5 * episodes"]
"""


@pytest.fixture
def compile_cache(tmp_path_factory, monkeypatch):
    cache = tmp_path_factory.mktemp("jax_cache")
    monkeypatch.setenv("JAX_COMPILATION_CACHE_DIR", str(cache))
    monkeypatch.setenv("JAX_PERSISTENT_CACHE_MIN_COMPILE_TIME_SECS", "0")
    monkeypatch.setenv("PYTHONPATH", os.pathsep.join([str(ROOT), os.environ.get("PYTHONPATH", "")]))
    return cache


def _kill_after_a_checkpoint(command: list[str], run_dir: Path, timeout: float = 300):
    worker = subprocess.Popen(command, stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)
    deadline = time.monotonic() + timeout
    while time.monotonic() < deadline and worker.poll() is None:
        steps = [p for p in (run_dir / "checkpoints").glob("*") if p.name.isdigit()]
        if len(steps) >= 2:  # the first one committed and its checksums written
            break
        time.sleep(0.05)
    worker.send_signal(signal.SIGKILL)  # no handler, no checkpoint: as a crash or an OOM kill
    worker.wait()


def test_a_killed_worker_resumes_and_the_sweep_reports(tmp_path, compile_cache, capsys):
    study = tmp_path / "tiny.toml"
    study.write_text(textwrap.dedent(STUDY))
    out = tmp_path / "sweep"
    first = [sys.executable, "-m", "advisor_jax.cli.main", "sweep", str(study), "--out", str(out),
             "--piece", "0", "--no-progress"]  # fmt: skip
    plan = None
    for _ in range(3):  # the first call plans (one piece of 4 agents) and starts it
        run_dir = out / "runs" / "000-ADDPG_AfD-episodes20"
        _kill_after_a_checkpoint(first, run_dir)
        plan = json.loads((out / "plan.json").read_text())
        if json.loads((run_dir / "run.json").read_text())["status"] == "running":
            break  # killed mid-population (else it finished first: try a longer window)
    assert [p["agents"] for p in plan["pieces"]] == [4]
    assert json.loads((run_dir / "run.json").read_text())["status"] == "running"

    main(["sweep", str(study), "--out", str(out), "--no-progress"])  # the kept plan, all pieces
    log = (out / "logs" / "000-ADDPG_AfD-episodes20.log").read_text()
    assert "resuming" in log and "at environment step" in log
    for piece in plan["pieces"]:
        summary = json.loads((out / "runs" / piece["name"] / "run.json").read_text())
        assert summary["status"] == "finished"
        assert summary["episodes_completed"] == [20] * 4
        assert summary["command"].endswith(f"--piece {piece['index']}")
    main(["sweep", str(study), "--out", str(out), "--no-progress"])  # nothing left to do
    assert "1 of 1 pieces finished" in capsys.readouterr().err

    report = tmp_path / "report"
    main(["report", str(out), "--out", str(report)])
    fig6 = json.loads((report / "fig6.json").read_text())
    (series,) = fig6["series"]
    assert [p["settings"]["advisor_episodes"] for p in series["points"]] == [0.0, 10.0]
    assert all(p["seeds"] == 2 for p in series["points"])
    assert {"table1.png", "fig6.png", "fig8.png", "fig10.png", "report.md"} <= {
        p.name for p in report.iterdir()
    }
