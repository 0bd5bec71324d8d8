"""experiments/table2.py on hand-made physical-arena runs: the success per budget (final
and kept actors), the collision speed pooled over seeds, the paired comparison with the
paper's best type, and what is left out."""

from __future__ import annotations

import argparse
import dataclasses
import json
import sys
from pathlib import Path

import numpy as np
import pytest

sys.path.insert(0, str(Path(__file__).resolve().parents[2] / "experiments"))

import table2  # noqa: E402

from advisor_jax.agent.config import preset  # noqa: E402


def _evaluation(success, collision, speed, speed_sd, episodes=20):
    return {
        "success": success,
        "collision": collision,
        "timeout": [
            None if s is None else 1 - s - c for s, c in zip(success, collision, strict=True)
        ],
        "collision_speed": speed,
        "collision_speed_sd": speed_sd,
        "episodes": episodes,
    }


def _run(root: Path, agent: str, final: dict, kept: dict, arena: str = "physical") -> Path:
    """A finished run of ``agent`` with seeds 0.. as run_training writes its run.json."""
    cfg, hp = preset("physical", agent)
    config = dataclasses.asdict(cfg)
    config["arena"] = arena
    n = len(final["success"])
    agents = [{**dataclasses.asdict(hp), "seed": s, "index": s} for s in range(n)]
    run_dir = root / agent.replace("+", "_")
    run_dir.mkdir(parents=True)
    summary = {
        "agent": agent,
        "preset": "physical",
        "device": "cpu",
        "created": "2026-11-24T00:00",
        "config": config,
        "agents": agents,
        "status": "finished",
        "evaluation": {arena: final},
        "evaluation_at_episode": {str(k): {arena: v} for k, v in kept.items()},
    }
    (run_dir / "run.json").write_text(json.dumps(summary))
    (run_dir / "command.json").write_text(json.dumps({"command": f"advisor-jax train {agent}"}))
    return run_dir


def test_pooled_collision_speed_is_the_moments_over_all_collisions():
    # agent 0: 2 collisions at 0.2 and 0.4 (mean 0.3, sd 0.1); agent 1: 1 at 0.6; agent 2 none
    ev = _evaluation([0.5, 0.5, 0.5], [0.1, 0.05, 0.0], [0.3, 0.6, None], [0.1, 0.0, None])
    pooled = table2.pooled_collision_speed(ev)
    speeds = np.array([0.2, 0.4, 0.6])
    assert pooled["collisions"] == 3
    assert pooled["mean"] == pytest.approx(speeds.mean())
    assert pooled["sd"] == pytest.approx(speeds.std())
    none = _evaluation([1.0], [0.0], [None], [None])
    assert table2.pooled_collision_speed(none) == {"collisions": 0, "mean": None, "sd": None}
    old = dict(ev, collision_speed_sd=None)  # an eval.json from before the spread was kept
    with pytest.raises(ValueError, match="collision_speed_sd missing"):
        table2.pooled_collision_speed(old)


def test_summary_tables_budgets_comparisons_and_the_advisor(tmp_path):
    runs = tmp_path / "runs"
    nothing = [0.0, 0.0, 0.0]
    _run(
        runs,
        "ATD3+AfDP",
        _evaluation([0.8, 0.7, 0.9], [0.1, 0.0, 0.0], [0.3, None, None], [0.1, None, None]),
        {100: _evaluation([0.4, 0.5, 0.6], nothing, [None] * 3, [None] * 3)},
    )
    _run(
        runs,
        "DDPG",
        _evaluation([0.5, 0.6, 0.6], [0.05, 0.05, 0.0], [0.5, 0.7, None], [0.0, 0.0, None]),
        {100: _evaluation([0.3, 0.3, 0.4], nothing, [None] * 3, [None] * 3)},
    )
    _run(runs, "ADDPG", _evaluation([0.1], [0.0], [None], [None]), {}, arena="training")
    advisor = tmp_path / "advisor.json"
    advisor.write_text(
        json.dumps(
            {"arena": "physical", "episodes": 100, "success_rate": 0.3, "collision_rate": 0.1,
             "mean_collision_speed": 0.35, "collision_speed_sd": 0.2}
        )
    )  # fmt: skip
    out = tmp_path / "out"
    table2.summarize(argparse.Namespace(runs=[runs], advisor=advisor, out=out))
    record = json.loads((out / "table2.json").read_text())
    assert record["budgets"] == [100, 200]
    assert list(record["agents"]) == ["DDPG", "ATD3+AfDP"]  # the paper's row order
    best = record["agents"]["ATD3+AfDP"]
    assert best["success"] == {"100": [0.4, 0.5, 0.6], "200": [0.8, 0.7, 0.9]}
    assert best["collision_speed"] == pytest.approx({"collisions": 2, "mean": 0.3, "sd": 0.1})
    ddpg = record["agents"]["DDPG"]["collision_speed"]  # one collision each at 0.5 and 0.7
    assert ddpg == pytest.approx({"collisions": 2, "mean": 0.6, "sd": 0.1})
    assert record["advisor"]["collisions"] == 10 and record["advisor"]["mean"] == 0.35
    versus = {c["budget"]: c for c in record["versus_best"]}
    diffs = np.array([0.8 - 0.5, 0.7 - 0.6, 0.9 - 0.6]) * 100
    assert versus[200]["mean"] == pytest.approx(diffs.mean())
    assert versus[200]["half"] == pytest.approx(4.302653 * diffs.std(ddof=1) / 3**0.5)
    assert versus[100]["mean"] == pytest.approx(100 * (0.1 + 0.2 + 0.2) / 3)
    assert versus[200]["verdict"] == "not resolved"  # 23.3 ± 28.7
    assert versus[100]["verdict"] == "holds"  # 16.7 ± 14.3
    assert any(
        "ADDPG" in n and "physical arena, left out" in n for n in record["provenance"]["notes"]
    )
    text = (out / "table2.md").read_text()
    assert "| ATD3+AfDP | 50.0 ± 24.8 % | 80.0 ± 24.8 % | 48.3 / 69.3 / 75.3 |" in text
    assert "| Advisor | 0.35 ± 0.20 | 10 | 0.36 ± 0.24 |" in text
    assert (out / "table2.png").stat().st_size > 0


def test_no_physical_runs_is_an_error(tmp_path):
    runs = tmp_path / "runs"
    _run(runs, "DDPG", _evaluation([0.1], [0.0], [None], [None]), {}, arena="training")
    with pytest.raises(SystemExit, match="no finished physical-arena runs"):
        table2.summarize(argparse.Namespace(runs=[runs], advisor=None, out=tmp_path / "out"))
