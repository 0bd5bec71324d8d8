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
from advisor_jax.agent.settings import flat_items, replace_flat


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


def _run(
    root: Path, agent: str, final: dict, kept: dict, arena: str = "physical", **hp_overrides
) -> Path:
    """A finished run of ``agent`` with seeds 0.. as run_training writes its run.json."""
    cfg, hp = preset("physical", agent)
    hp = replace_flat(hp, **hp_overrides)
    config = dataclasses.asdict(cfg)
    config["arena"] = arena
    n = len(final["success"])
    agents = [{**flat_items(hp), "seed": s, "index": s} for s in range(n)]
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
    assert best["collision_speed"] == pytest.approx(
        {"collisions": 2, "mean": 0.3, "sd": 0.1, "episodes": 60}
    )
    ddpg = record["agents"]["DDPG"]["collision_speed"]  # one collision each at 0.5 and 0.7
    assert ddpg == pytest.approx({"collisions": 2, "mean": 0.6, "sd": 0.1, "episodes": 60})
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
    assert "| Advisor | 0.35 ± 0.20 | 10 of 100 | 0.36 ± 0.24 |" in text
    assert "| DDPG | 0.60 ± 0.10 | 2 of 60 | 0.43 ± 0.26 |" in text
    assert (out / "table2.png").stat().st_size > 0


def test_no_physical_runs_is_an_error(tmp_path):
    runs = tmp_path / "runs"
    _run(runs, "DDPG", _evaluation([0.1], [0.0], [None], [None]), {}, arena="training")
    with pytest.raises(SystemExit, match="no finished physical-arena runs"):
        table2.summarize(argparse.Namespace(runs=[runs], advisor=None, out=tmp_path / "out"))


STABLE = dict(beta=1.0, beta_normalize=1.0, clip_actor_target=1.0, clip_q_target=1.0)


def test_settings_advisor_without_collisions_and_baseline_prior_phases(tmp_path):
    """What a reader needs beside the numbers: every row's settings (the physical preset's
    own changes such as ATD3's d = 3, the stable switches), why the never-colliding advisor
    has no speed, the advisor's command, and the baseline budgets that hold no RL."""
    runs = tmp_path / "runs"
    nothing = [0.0, 0.0, 0.0]
    _run(
        runs,
        "ATD3+AfDP",
        _evaluation([0.8, 0.7, 0.9], [0.1, 0.1, 0.1], [0.2, 0.3, 0.2], [0.0, 0.0, 0.0], 10),
        {100: _evaluation([0.4, 0.5, 0.6], nothing, [None] * 3, [None] * 3, 10)},
        **STABLE,
    )
    _run(  # the physical preset's LfD: 100 demonstration episodes of its 200
        runs,
        "LfD",
        _evaluation([0.5, 0.6, 0.6], [0.1, 0.1, 0.1], [0.5, 0.5, 0.6], [0.0, 0.0, 0.0], 10),
        {100: _evaluation([0.0, 0.1, 0.0], nothing, [None] * 3, [None] * 3, 10)},
        **STABLE,
    )
    advisor = tmp_path / "advisor_physical.json"
    advisor.write_text(
        json.dumps(
            {"arena": "physical", "episodes": 1600, "success_rate": 0.38625, "collision_rate": 0.0,
             "mean_collision_speed": None, "collision_speed_sd": None}
        )
    )  # fmt: skip
    (tmp_path / "advisor_physical_command.json").write_text(
        json.dumps(
            {"command": "advisor-jax evaluate --policy advisor --arena physical --episodes 1600",
             "device": "NVIDIA H200", "created": "2026-11-24T06:44:00+00:00"}
        )
    )  # fmt: skip
    out = tmp_path / "out"
    table2.summarize(argparse.Namespace(runs=[runs], advisor=advisor, out=out))
    text = (out / "table2.md").read_text()
    record = json.loads((out / "table2.json").read_text())

    # settings: the preset's own changes (policy delay included), the stable switches, d
    assert "`--preset physical` (= `paper` with buffer_size 100000→50000" in text
    assert "policy_delay 4→3" in text
    assert "beta=1, beta_normalize=1, clip_actor_target=1, clip_q_target=1 (the `stable`" in text
    assert "| ATD3+AfDP | physical | 200 | atd3 | 3 (`physical`; `paper`: 4) |" in text
    assert "| LfD | physical | 200 | ddpg | 1 (DDPG family: no delay) | 100 |" in text
    assert record["agents"]["ATD3+AfDP"]["learner"]["delay"] == 3

    # the advisor never collides: said in words, not a number; its command and device shown
    assert "| Advisor | none: no collision | 0 of 1600 | 0.36 ± 0.24 |" in text
    assert "The advisor never collided in its 1600 physical-arena episodes" in text
    assert "success 38.6 %" in text
    assert (
        "Advisor evaluation (NVIDIA H200, 2026-11-24): "
        "`advisor-jax evaluate --policy advisor --arena physical --episodes 1600`" in text
    )
    assert record["advisor"]["mean"] is None and record["advisor"]["collisions"] == 0

    # LfD at 100 episodes has had no RL (not even imitation): marked, and explained
    assert record["agents"]["LfD"]["prior_episodes"] == 100
    assert record["agents"]["LfD"]["no_rl_budgets"] == [100]
    assert record["agents"]["ATD3+AfDP"]["no_rl_budgets"] == []
    assert "| LfD | 3.3 ± 14.3 % † | 56.7 ± 14.3 % |" in text
    assert "its actor there is the untrained initial one" in text
    versus = {c["budget"]: c for c in record["versus_best"]}
    assert versus[100]["no_rl"] and not versus[200]["no_rl"]
    assert "| LfD | 100 | 3 | +46.7 ± 28.7 | holds † |" in text

    # Table 3's claim, paired by seed on each seed's mean collision speed
    (speed,) = record["afp_collision_speed"]
    assert (speed["afp"], speed["other"], speed["seeds"]) == ("ATD3+AfDP", "LfD", 3)
    diffs = np.array([0.2 - 0.5, 0.3 - 0.5, 0.2 - 0.6])
    assert speed["mean"] == pytest.approx(diffs.mean())
    assert speed["half"] == pytest.approx(4.302653 * diffs.std(ddof=1) / 3**0.5)
    assert speed["verdict"] == "holds"


def test_a_shorter_run_of_a_type_gives_its_budget_in_place_of_the_kept_actor(tmp_path):
    """A baseline's prior phases take half its budget, so LfD trained for 100 episodes (50
    demonstrations) is a run of its own: its final evaluation is the 100 column (marked ‡,
    with the kept actor it replaces named), not the 200-episode run's actor at episode 100
    (still before imitation: †). A second run at the same budget is left out."""
    long_runs, short_runs, again = tmp_path / "long", tmp_path / "short", tmp_path / "again"
    nothing = [0.0, 0.0, 0.0]
    _run(
        long_runs,
        "ATD3+AfDP",
        _evaluation([0.8, 0.7, 0.9], nothing, [None] * 3, [None] * 3, 10),
        {100: _evaluation([0.4, 0.5, 0.6], nothing, [None] * 3, [None] * 3, 10)},
    )
    _run(
        long_runs,
        "LfD",
        _evaluation([0.5, 0.6, 0.6], nothing, [None] * 3, [None] * 3, 10),
        {100: _evaluation([0.0, 0.1, 0.0], nothing, [None] * 3, [None] * 3, 10)},
    )
    for root, success in ((short_runs, [0.7, 0.8, 0.9]), (again, [0.2, 0.2, 0.2])):
        run = _run(root, "LfD", _evaluation(success, nothing, [None] * 3, [None] * 3, 10), {},
                   demo_episodes=50.0)  # fmt: skip
        summary = json.loads((run / "run.json").read_text())
        summary["config"]["episodes"] = 100  # N_total 100
        (run / "run.json").write_text(json.dumps(summary))
    out = tmp_path / "out"
    args = argparse.Namespace(runs=[long_runs, short_runs, again], advisor=None, out=out)
    table2.summarize(args)
    record = json.loads((out / "table2.json").read_text())
    lfd = record["agents"]["LfD"]
    assert lfd["success"]["100"] == pytest.approx([0.7, 0.8, 0.9])  # the separate run
    assert lfd["success"]["200"] == pytest.approx([0.5, 0.6, 0.6])
    assert lfd["no_rl_budgets"] == []  # 50 prior episodes of 100: RL after them
    separate = lfd["separate_runs"]["100"]
    assert separate["prior_episodes"] == 50 and separate["dir"] == str(short_runs / "LfD")
    assert separate["kept_actor_replaced"]["mean"] == pytest.approx(100 / 30)
    text = (out / "table2.md").read_text()
    assert "| LfD | 80.0 ± 24.8 % ‡ | 56.7 ± 14.3 % |" in text
    assert "LfD at 100: demo_episodes=50, prior phases 50 episodes" in text
    assert "the 200-episode run's actor at episode 100: 3.3 ± 14.3 %" in text
    assert any("a second LfD run of 100 episodes" in n for n in record["provenance"]["notes"])
    versus = {c["budget"]: c for c in record["versus_best"] if c["other"] == "LfD"}
    assert versus[100]["mean"] == pytest.approx(100 * (-0.3 - 0.3 - 0.3) / 3)
