"""experiments/calibrate_arena.py at tiny sizes on the CPU: DDPG trains in an mjx arena
setting, the advisor is evaluated beside it, and the JSON and table hold one row per
(candidate, preset). (Reusing a finished run is ``common.train_or_resume``'s.)"""

from __future__ import annotations

import json
import sys
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parents[2] / "experiments"))

import calibrate_arena  # noqa: E402


def test_smoke_trains_and_evaluates(tmp_path):
    args = calibrate_arena.Args(
        candidates=("mjx:wheel_torque_max=0.5",),
        presets=("quick",),
        seeds=2,
        episodes=2,
        max_episode_steps=20,
        precision="fp32",
        eval_episodes=4,
        advisor_episodes=4,
        arenas=("training",),
        runs=str(tmp_path / "runs"),
        out=str(tmp_path / "result"),
        date="2026-11-26",
    )
    first = calibrate_arena.main(args)
    (ddpg,) = first["ddpg"]
    assert ddpg["status"] == "trained" and ddpg["seeds"] == 2 and ddpg["diverged"] == 0
    run = json.loads((Path(ddpg["run_dir"]) / "run.json").read_text())
    assert run["config"]["motion"] == "mjx:wheel_torque_max=0.5"
    assert run["config"]["agent"]["algo"] == "ddpg" and run["config"]["episodes"] == 2
    rates = ddpg["arenas"]["training"]
    total = sum(rates[k]["mean"] for k in ("success", "collision", "timeout"))
    assert abs(total - 1.0) < 1e-6
    (advisor,) = first["advisor"]
    assert advisor["arenas"]["training"]["episodes"] == 4
    saved = json.loads((tmp_path / "result.json").read_text())
    assert saved["settings"]["candidates"] == ["mjx:wheel_torque_max=0.5"]
    table = (tmp_path / "result.md").read_text()
    assert "| DDPG | `mjx:wheel_torque_max=0.5` | quick |" in table
    assert "| advisor | `mjx:wheel_torque_max=0.5` | – |" in table


def test_a_later_call_of_the_same_study_keeps_the_earlier_rows(tmp_path):
    args = calibrate_arena.Args(candidates=("mjx",), presets=("paper",), out=str(tmp_path / "r"))
    settings = json.loads(json.dumps(calibrate_arena.dataclasses.asdict(args)))
    rows = {"advisor": [{"candidate": "kinematic"}], "ddpg": [{"candidate": "kinematic"}]}
    (tmp_path / "r.json").write_text(json.dumps({"settings": settings, **rows}))
    assert calibrate_arena.earlier_rows(args) == (rows["advisor"], rows["ddpg"])
    other = calibrate_arena.dataclasses.replace(args, seeds=4)  # another study
    assert calibrate_arena.earlier_rows(other) == ([], [])
