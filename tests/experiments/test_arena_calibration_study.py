"""The arena calibration studies (experiments/studies/arena_calibration*.toml): each motion
model is one static setting, and at tiny sizes on the CPU the setting reaches the run and
the report's points."""

from __future__ import annotations

import json
import os
import textwrap
from pathlib import Path

from advisor_jax.cli.main import main
from advisor_jax.study.spec import load_study
from advisor_jax.training.request import build_run

ROOT = Path(__file__).resolve().parents[2]
MOTIONS = ["kinematic", "mjx", "mjx:wheel_torque_max=0.5", "mjx:wheel_torque_max=0.8"]


def test_the_studies_train_ddpg_in_every_candidate_arena():
    for name, preset in (("arena_calibration", "stable"), ("arena_calibration_paper", "paper")):
        study = load_study(ROOT / "experiments" / "studies" / f"{name}.toml")
        assert [g.agent for g in study.groups] == ["DDPG"] * 4
        assert study.preset == preset and len(study.seeds) == 16
        configs = [build_run(study.args(g))[0] for g in study.groups]
        assert [c.motion for c in configs] == MOTIONS
        assert {c.episodes for c in configs} == {500}


TINY = """
[study]
name = "tiny_arena"
preset = "quick"
agents = ["DDPG"]
seeds = 2
eval_seed = 0
eval_episodes = 2

[static]
episodes = 2
max_episode_steps = 20
chunk_steps = 20
batch_size = 16
buffer_size = 256
motion = ["mjx:wheel_torque_max=0.5"]
"""


def test_a_tiny_sweep_trains_in_the_mjx_arena_and_reports_it(tmp_path, monkeypatch):
    monkeypatch.setenv("PYTHONPATH", os.pathsep.join([str(ROOT), os.environ.get("PYTHONPATH", "")]))
    study = tmp_path / "tiny.toml"
    study.write_text(textwrap.dedent(TINY))
    out = tmp_path / "sweep"
    main(["sweep", str(study), "--out", str(out), "--no-progress"])
    (run_json,) = (out / "runs").glob("*/run.json")
    summary = json.loads(run_json.read_text())
    assert summary["status"] == "finished"
    assert summary["config"]["motion"] == "mjx:wheel_torque_max=0.5"
    report = tmp_path / "report"
    main(["report", str(out), "--out", str(report), "--items", "table1"])
    (point,) = json.loads((report / "table1.json").read_text())["points"]
    assert point["settings"]["motion"] == "mjx:wheel_torque_max=0.5"
