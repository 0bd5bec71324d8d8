"""experiments/afp_study.py and table1.py without training: how the study is cut into
pieces, the Welch interval, and the summaries of hand-made run directories."""

from __future__ import annotations

import argparse
import dataclasses
import itertools
import json
import re
import sys
from pathlib import Path

import numpy as np
import pytest

sys.path.insert(0, str(Path(__file__).resolve().parents[2] / "experiments"))

import afp_study  # noqa: E402
import common  # noqa: E402
import table1  # noqa: E402

from advisor_jax.agent.config import HPARAM_NAMES, preset  # noqa: E402


@pytest.mark.parametrize(
    "sizes, n_seeds, max_agents, pieces",
    [
        ((4, 2, 1), 16, 25, 6),
        ((4, 2, 1), 16, 16, 8),
        ((4, 2, 2), 16, 25, 12),
        ((1,), 16, 25, 1),
        ((3,), 5, 4, 5),
    ],
)
def test_split_covers_every_agent_once(sizes, n_seeds, max_agents, pieces):
    grid = {f"axis{i}": [float(v) for v in range(n)] for i, n in enumerate(sizes)}
    seeds = list(range(n_seeds))
    split = afp_study.split_population(grid, seeds, max_agents)
    assert len(split) == pieces
    agents = []
    for sub, block in split:
        assert list(sub) == list(grid)  # a sub-grid of every axis: run_training's product
        assert len(block) * np.prod([len(v) for v in sub.values()]) <= max_agents
        agents += [(*point, s) for point in itertools.product(*sub.values()) for s in block]
    assert sorted(agents) == sorted(
        (*point, s) for point in itertools.product(*grid.values()) for s in seeds
    )


def _study_args(**kw):
    args = argparse.Namespace(
        preset="paper",
        agents=list(afp_study.AFP_AGENTS),
        controls=None,
        betas=[0.01, 0.1, 1.0, 10.0],
        modes=[0.0, 1.0],
        clip=[0.0],
        seeds=16,
        seed=0,
        episodes=[500, 200],
        eval_episodes=100,
        max_agents=[16, 25],
        separate_episodes=False,
        hp=[],
    )
    vars(args).update(kw)
    afp_study._check_options(args)
    return args


def test_study_pieces_names_and_sizes():
    pieces = afp_study.study_pieces(_study_args())
    names = [p.name for p in pieces]
    assert len(set(names)) == len(names)
    assert all(re.fullmatch(r"[A-Za-z0-9._-]+", n) for n in names)  # $OUT's allowed names
    # 3 AfP types × 8 points + 2 controls, 16 seeds, at 500 episodes; 200 is a snapshot
    assert sum(p.n_agents for p in pieces) == (3 * 8 + 2) * 16
    assert {p.episodes for p in pieces} == {500} and max(p.n_agents for p in pieces) <= 16
    assert afp_study.snapshot_budgets(_study_args(), 500) == (200,)
    assert pieces[0].agent == "ADDPG+AfD" and pieces[0].episodes == 500
    apart = _study_args(separate_episodes=True)  # every budget trained on its own
    pieces = afp_study.study_pieces(apart)
    assert sum(p.n_agents for p in pieces) == 2 * (3 * 8 + 2) * 16
    assert max(p.n_agents for p in pieces if p.episodes == 200) <= 25
    assert afp_study.snapshot_budgets(apart, 500) == ()
    assert "--separate-episodes" in afp_study._study_argv(apart)


def test_welch_interval_matches_scipy():
    from scipy import stats

    a, b = [0.9, 0.8, 0.85, 0.7, 0.95], [0.6, 0.55, 0.7, 0.5]
    diff, half = afp_study.welch_ci95(a, b)
    low, high = stats.ttest_ind(a, b, equal_var=False).confidence_interval()
    assert diff == pytest.approx((low + high) / 2) and half == pytest.approx((high - low) / 2)


def _fake_run(root: Path, agent: str, episodes: int, grid: dict, seeds, success, **extra):
    """A finished run directory as run_training writes it (run.json, metrics.npz) with
    ``success[i]`` the training-arena success of agent i (validation: half of it)."""
    from advisor_jax.training.population import build_population

    _, hp = preset("quick", agent)
    _, agents = build_population(hp, grid, seeds)
    n = len(agents)
    run_dir = root / f"{agent.replace('+', '_')}-e{episodes}-{len(list(root.iterdir()))}"
    run_dir.mkdir(parents=True)
    evaluation = {
        arena: {
            "success": [s * f for s in success],
            "collision": [0.0] * n,
            "timeout": [1 - s * f for s in success],
            "collision_speed": [0.1] * n,
            "episodes": 10,
        }
        for arena, f in (("training", 1.0), ("validation", 0.5))
    }
    summary = {
        "agent": agent,
        "preset": "quick",
        "device": "cpu",
        "created": "2026-11-24T00:00",
        "config": {"episodes": episodes},
        "grid": grid,
        "agents": agents,
        "status": "finished",
        "diverged": [],
        "evaluation": evaluation,
        **extra,
    }
    (run_dir / "run.json").write_text(json.dumps(summary))
    # three chunks of 100 steps; agent i finishes in chunk 1 (env_steps 150): its value there
    replaced = np.tile([0.1, 0.2, 0.9], (n, 1)) + np.arange(n)[:, None]
    curves = np.linspace(0.0, 1.0, n * episodes).reshape(n, episodes)
    np.savez(
        run_dir / "metrics.npz",
        **{
            "log/step": np.array([100, 200, 300]),
            "env_steps": np.full(n, 150),
            "log/advisor/replaced": replaced,
            "outcome": np.ones((n, episodes), np.int32),
            "length": np.full((n, episodes), 30, np.int32),
            "reward_per_step": curves,
            "collision_speed": curves,
        },
    )
    return run_dir


def test_summarize_pools_pieces_and_compares_with_the_control(tmp_path):
    runs = tmp_path / "runs"
    runs.mkdir()
    grid = {"beta": [1.0], "beta_normalize": [0.0, 1.0], "clip_actor_target": [0.0]}
    _fake_run(runs, "ATD3+AfDP", 6, grid, [0, 1], [0.9, 0.8, 0.3, 0.4])
    _fake_run(runs, "ATD3+AfDP", 6, grid, [2], [0.7, 0.5])
    _fake_run(runs, "ATD3+AfDP", 6, grid, [2], [0.0, 0.0])  # seed 2 again: counted once
    _fake_run(runs, "ATD3+AfD", 6, {"clip_actor_target": [0.0]}, [0, 1, 2], [0.6, 0.5, 0.55])
    _fake_run(runs, "ATD3+AfD", 6, {}, [3], [0.2], status="interrupted")  # left out
    out = tmp_path / "out"
    afp_study.summarize(argparse.Namespace(runs=[runs], out=out, collapse_below=0.5))
    record = json.loads((out / "afp_study.json").read_text())
    points = {(p["agent"], p["beta_normalize"]): p for p in record["points"]}
    literal = points[("ATD3+AfDP", 0.0)]
    assert literal["seeds"] == [0, 1, 2]
    assert literal["training"]["per_seed"] == pytest.approx([0.9, 0.8, 0.7])
    assert literal["validation"]["collapsed"] == 3  # 0.45, 0.4, 0.35 < 0.5
    assert literal["effect"]["training"]["diff"] == pytest.approx(0.8 - 0.55)
    paired = literal["effect"]["training"]["paired"]  # seeds 0, 1, 2 in both
    assert paired["seeds"] == 3 and paired["diff"] == pytest.approx((0.3 + 0.3 + 0.15) / 3)
    assert paired["ci95"] == pytest.approx(4.302653 * np.std([0.3, 0.3, 0.15], ddof=1) / 3**0.5)
    assert literal["settings"] == {"preset": "quick", "episodes": 6}  # β = 1: an axis
    # last chunk of each agent's own training (chunk 1), means over seeds: agents 0, 1, 4
    assert literal["diagnostics"]["advisor/replaced"] == pytest.approx(0.2 + (0 + 1 + 0) / 3)
    assert points[("ATD3+AfDP", 1.0)]["training"]["collapsed"] == 2
    assert "effect" not in points[("ATD3+AfD", 0.0)]
    assert any("counted once" in n for n in record["provenance"]["notes"])
    assert any("interrupted" in n for n in record["provenance"]["notes"])
    assert (out / "afp_study.png").stat().st_size > 0
    assert "Welch 95 % interval" in (out / "afp_study.md").read_text()


def test_summarize_reads_the_actors_kept_at_a_smaller_budget(tmp_path):
    """A 6-episode run with --snapshot-episodes 3 gives a 3-episode point of its own, with
    the snapshot's evaluation and the diagnostics of the chunk in which episode 3 ended."""
    runs = tmp_path / "runs"
    runs.mkdir()
    grid = {"beta": [1.0], "beta_normalize": [1.0], "clip_actor_target": [0.0]}
    at_3 = {
        arena: {"success": [0.2 * f, None], "timeout": [0.5, None], "episodes": 10}
        for arena, f in (("training", 1.0), ("validation", 0.5))
    }
    _fake_run(runs, "ATD3+AfDP", 6, grid, [0, 1], [0.9, 0.8], evaluation_at_episode={"3": at_3})
    table1 = tmp_path / "table1"  # a second folder: its DDPG is no study type
    table1.mkdir()
    _fake_run(table1, "DDPG", 6, {}, [0], [0.7])
    out = tmp_path / "out"
    afp_study.summarize(argparse.Namespace(runs=[runs, table1], out=out, collapse_below=0.5))
    record = json.loads((out / "afp_study.json").read_text())
    points = {p["episodes"]: p for p in record["points"]}
    assert points[6]["training"]["per_seed"] == pytest.approx([0.9, 0.8])
    assert points[6]["snapshot_seeds"] == []
    early = points[3]
    assert early["training"]["per_seed"] == [0.2, None] and early["diverged"] == [1]
    assert early["validation"]["per_seed"] == pytest.approx([0.1, None])
    assert early["settings"] == {"preset": "quick", "episodes": 3}
    assert early["snapshot_seeds"] == [0, 1]
    # 3 episodes × 30 steps = 90: chunk 0 (step 100) of each agent, not its last chunk
    assert early["diagnostics"]["advisor/replaced"] == pytest.approx(0.1 + (0 + 1) / 2)
    assert "kept at episode 3 of longer runs" in (out / "afp_study.md").read_text()
    assert len(record["points"]) == 2
    assert any("DDPG is not a study agent type" in n for n in record["provenance"]["notes"])


def test_table1_json_schema(tmp_path):
    chosen, literal = tmp_path / "chosen", tmp_path / "literal"
    for root, extra in ((chosen, {"beta": [1.0], "beta_normalize": [1.0]}), (literal, {})):
        root.mkdir()
        for agent in ("ATD3+AfDP", "ADDPG+AfD"):
            _fake_run(root, agent, 6, extra, [0, 1, 2], [0.9, 0.6, 0.75])
    out = tmp_path / "out"
    table1.summarize(argparse.Namespace(runs=[chosen, literal], out=out))
    record = json.loads((out / "table1.json").read_text())
    assert set(record) == {"seeds", "agents"} and record["seeds"] == 3
    row = record["agents"]["ATD3+AfDP"]
    assert row["training"] == pytest.approx([0.9, 0.6, 0.75])
    assert row["validation"] == pytest.approx([0.45, 0.3, 0.375])
    assert row["settings"] == {"preset": "quick", "episodes": 6, "beta": 1.0, "beta_normalize": 1.0}
    assert set(row["settings"]) - {"preset", "episodes"} <= set(HPARAM_NAMES)
    text = (out / "table1.md").read_text()
    assert "beta=1, beta_normalize=1" in text and "the preset's hyperparameters" in text


def test_table1_pairs_seeds_and_states_which_orderings_hold(tmp_path):
    """Paired by seed: ADDPG+AfP − ADDPG+AfD = (+0.2, +0.1, +0.3) → 20 ± 24.8 points
    (t_0.975,2 = 4.303, sd 10, n 3): not resolved; with 4 seeds (+0.2, +0.1, +0.3, +0.2),
    20 ± 13.0: holds. ADDPG+AfDP is worse than ADDPG+AfP in every seed: reversed."""
    root = tmp_path / "runs"
    root.mkdir()
    seeds = [0, 1, 2, 3]
    _fake_run(root, "ADDPG+AfD", 6, {}, seeds, [0.5, 0.6, 0.4, 0.5])
    _fake_run(root, "ADDPG+AfP", 6, {}, seeds, [0.7, 0.7, 0.7, 0.7])
    _fake_run(root, "ADDPG+AfDP", 6, {}, seeds, [0.1, 0.2, 0.0, 0.15])
    run = next(root.glob("ADDPG_AfDP*"))
    (run / "command.json").write_text(json.dumps({"command": "advisor-jax train --agent X"}))
    rows = table1.load_table(root)
    found = {(c["better"], c["worse"]): c for c in table1.comparisons(rows)}
    afp = found["ADDPG+AfP", "ADDPG+AfD"]["training"]
    assert afp["seeds"] == 4 and afp["verdict"] == "holds"
    assert afp["mean"] == pytest.approx(20.0) and afp["half"] == pytest.approx(12.99, abs=0.01)
    assert found["ADDPG+AfDP", "ADDPG+AfP"]["training"]["verdict"] == "reversed"
    three = {**rows[0], "by_seed": {"training": {s: rows[0]["by_seed"]["training"][s]
                                                 for s in (0, 1, 2)}}}  # fmt: skip
    d = table1.paired_difference(rows[1], three, "training")  # seeds 0-2 only
    assert d["seeds"] == 3 and d["half"] == pytest.approx(24.84, abs=0.01)
    assert d["verdict"] == "not resolved"
    assert "ADDPG > DDPG" not in str(found)  # rows that are absent are not compared
    out = tmp_path / "out"
    table1.summarize(argparse.Namespace(runs=[root], out=out))
    text = (out / "table1.md").read_text()
    assert "ADDPG+AfDP > ADDPG+AfP" in text and "(reversed)" in text
    assert "`advisor-jax train --agent X`" in text  # the device run's command.json
    # the learning table: every fake episode reached the goal, 6 episodes = one block
    assert "| agent | 1–6 |" in text and "| ADDPG+AfDP | 100 |" in text


def test_export_copies_only_the_small_files(tmp_path):
    run = tmp_path / "run"
    (run / "checkpoints" / "40").mkdir(parents=True)
    (run / "params").mkdir()
    for name in ("run.json", "eval.json", "metrics.npz", "learning_curve.png"):
        (run / name).write_text(name)
    common.export_small_files(run, tmp_path / "out" / "run")
    assert sorted(p.name for p in (tmp_path / "out" / "run").iterdir()) == [
        "eval.json",
        "metrics.npz",
        "run.json",
    ]


def test_table1_names_the_settings_and_devices_that_differ(tmp_path):
    """A claim between rows trained at different settings says so, and rows trained on
    different devices are listed with theirs."""
    root = tmp_path / "runs"
    root.mkdir()
    seeds = [0, 1, 2]
    _fake_run(root, "ADDPG", 6, {"clip_q_target": [1.0]}, seeds, [0.8, 0.8, 0.9], device="gpu-a")
    _fake_run(root, "DDPG", 6, {}, seeds, [0.7, 0.6, 0.8], device="gpu-b")
    rows = table1.load_table(root)
    (claim,) = table1.comparisons(rows)
    assert (claim["better"], claim["worse"], claim["differs"]) == (
        "ADDPG",
        "DDPG",
        ["clip_q_target"],
    )
    lines = "\n".join(table1._table_lines(rows, root))
    assert "ADDPG > DDPG (differs: clip_q_target)" in lines
    assert "trained on gpu-b, 2026-11-24 (DDPG); gpu-a, 2026-11-24 (ADDPG)" in lines


def test_a_run_older_than_a_hyperparameter_reads_as_its_paper_value():
    """An agent row without ``clip_q_target`` was trained before the switch existed, so
    without the clip, even under a preset whose default now turns it on."""
    from advisor_jax.agent.config import HParams

    row = dataclasses.asdict(preset("stable", "ADDPG")[1])
    del row["clip_q_target"]
    summary = {"agent": "ADDPG", "preset": "stable", "config": {"episodes": 500}}
    settings = common.preset_differences(summary, row)
    assert settings == {
        "preset": "stable",
        "episodes": 500,
        "clip_q_target": HParams().clip_q_target,
    }
    assert settings["clip_q_target"] == 0.0


def test_agents_at_other_settings_are_points_of_their_own(tmp_path):
    """An ATD3+AfDP grid over lr_actor is not pooled with the study's point at the preset's
    lr_actor, and has no AfP effect where no control was trained at that lr_actor."""
    runs = tmp_path / "runs"
    runs.mkdir()
    axes = {"beta": [1.0], "beta_normalize": [1.0], "clip_actor_target": [0.0]}
    _fake_run(runs, "ATD3+AfDP", 6, axes, [0, 1], [0.9, 0.8])
    _fake_run(runs, "ATD3+AfDP", 6, {**axes, "lr_actor": [4e-5, 1e-4]}, [0, 1], [0.1] * 4)
    _fake_run(runs, "ATD3+AfD", 6, {"clip_actor_target": [0.0]}, [0, 1], [0.6, 0.5])
    out = tmp_path / "out"
    afp_study.summarize(argparse.Namespace(runs=[runs], out=out, collapse_below=0.5))
    record = json.loads((out / "afp_study.json").read_text())
    afp = {tuple(p["other"].items()): p for p in record["points"] if p["agent"] == "ATD3+AfDP"}
    assert set(afp) == {(), (("lr_actor", 4e-5),), (("lr_actor", 1e-4),)}
    assert afp[()]["training"]["per_seed"] == pytest.approx([0.9, 0.8])  # not pooled
    assert afp[()]["effect"]["training"]["paired"]["diff"] == pytest.approx(0.3)
    assert afp[(("lr_actor", 4e-5),)]["training"]["per_seed"] == pytest.approx([0.1, 0.1])
    assert "effect" not in afp[(("lr_actor", 4e-5),)]
    assert afp[(("lr_actor", 4e-5),)]["settings"]["lr_actor"] == pytest.approx(4e-5)
    assert not any("pooled anyway" in n for n in record["provenance"]["notes"])
    assert "scale-free, lr_actor=0.0001" in (out / "afp_study.md").read_text()


def test_static_settings_that_differ_from_the_preset_are_named():
    """--policy-delay 2 (an AgentConfig field, one compile) is named like a hyperparameter;
    an older run.json without a static field names nothing for it."""
    cfg = dataclasses.asdict(preset("stable", "ATD3+AfDP")[0])
    row = dataclasses.asdict(preset("stable", "ATD3+AfDP")[1])
    summary = {"agent": "ATD3+AfDP", "preset": "stable", "config": cfg}
    assert common.preset_differences(summary, row) == {"preset": "stable", "episodes": 500}
    cfg["agent"]["policy_delay"] = 2
    cfg["agent"]["actor_hidden"] = [64, 64]  # as JSON gives it back
    del cfg["agent"]["precision"]
    assert common.preset_differences(summary, row) == {
        "preset": "stable",
        "episodes": 500,
        "actor_hidden": (64, 64),
        "policy_delay": 2,
    }


def test_table1_pools_runs_of_one_type_and_refuses_a_seed_twice(tmp_path):
    """Seeds 0-2 and 3-5 of ATD3+AfDP trained as two runs are one row of six seeds; its
    claim against a type with seeds 0-2 pairs those three; a seed in both runs is an error."""
    root = tmp_path / "runs"
    root.mkdir()
    _fake_run(root, "ATD3+AfDP", 6, {}, [0, 1, 2], [0.9, 0.8, 0.7])
    _fake_run(root, "ATD3+AfDP", 6, {}, [3, 4, 5], [0.6, 0.5, 0.4])
    _fake_run(root, "LfD", 6, {}, [0, 1, 2], [0.5, 0.5, 0.5])
    rows = table1.load_table(root)
    assert [r["agent"] for r in rows] == ["ATD3+AfDP", "LfD"]
    pooled = rows[0]
    assert sorted(pooled["seeds"]) == [0, 1, 2, 3, 4, 5] and len(pooled["dirs"]) == 2
    assert sorted(pooled["success"]["training"]) == pytest.approx([0.4, 0.5, 0.6, 0.7, 0.8, 0.9])
    assert table1.row_metrics(pooled, "outcome").shape == (6, 6)
    (claim,) = table1.comparisons(rows)  # §6.2: ATD3+AfDP over the baselines
    assert (claim["kind"], claim["better"], claim["worse"]) == ("over baseline", "ATD3+AfDP", "LfD")
    assert claim["training"]["seeds"] == 3 and claim["training"]["mean"] == pytest.approx(30.0)
    out = tmp_path / "out"
    table1.summarize(argparse.Namespace(runs=[root], out=out))
    record = json.loads((out / "table1.json").read_text())
    assert record["seeds"] == 3 and len(record["agents"]["ATD3+AfDP"]["training"]) == 6
    text = (out / "table1.md").read_text()
    assert "Seeds 0-2 (ATD3+AfDP: 0-5)" in text and "| LfD | 3 |" in text
    _fake_run(root, "ATD3+AfDP", 6, {}, [5, 6, 7], [0.6, 0.5, 0.4])
    with pytest.raises(SystemExit, match=r"seeds \[5\] of ATD3\+AfDP"):
        table1.load_table(root)


def test_table1_rows_from_another_folder_replace_their_type(tmp_path):
    """--rows-from: the first table keeps its other types; the type found there is taken
    from there (its settings too), and the report says so."""
    chosen, other = tmp_path / "chosen", tmp_path / "other"
    for root in (chosen, other):
        root.mkdir()
    _fake_run(chosen, "ATD3+AfDP", 6, {}, [0, 1, 2], [0.5, 0.5, 0.5])
    _fake_run(chosen, "ADDPG+AfDP", 6, {}, [0, 1, 2], [0.6, 0.6, 0.6])
    _fake_run(other, "ATD3+AfDP", 6, {"beta": [2.0]}, [0, 1, 2], [0.9, 0.8, 0.9])
    out = tmp_path / "out"
    table1.summarize(argparse.Namespace(runs=[chosen], rows_from=[other], out=out))
    record = json.loads((out / "table1.json").read_text())
    assert record["agents"]["ATD3+AfDP"]["training"] == pytest.approx([0.9, 0.8, 0.9])
    assert record["agents"]["ATD3+AfDP"]["settings"]["beta"] == 2.0
    assert record["agents"]["ADDPG+AfDP"]["training"] == pytest.approx([0.6, 0.6, 0.6])
    text = (out / "table1.md").read_text()
    assert (
        f"ATD3+AfDP: the runs under `{other}`" in text
        and f"in place of those under `{chosen}`" in text
    )
    assert "--rows-from" in text  # the summarize command as run
