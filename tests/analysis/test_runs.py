"""The one loader: finished runs pooled into points; runs on other evaluation episodes refused."""

from __future__ import annotations

import json

import numpy as np
import pytest

from advisor_jax.analysis.rundata import compact_run
from advisor_jax.analysis.runs import load_runs, pool
from tests.analysis.fake_runs import write_run


def test_seeds_of_one_setting_pool_across_runs_and_a_repeated_seed_counts_once(tmp_path):
    write_run(tmp_path, "a", "DDPG", [0, 1], [0.8, 0.6])
    write_run(tmp_path, "b", "DDPG", [2, 3], [0.7, 0.5])
    write_run(tmp_path, "c", "DDPG", [3], [0.1])  # seed 3 again: the first one counts
    write_run(tmp_path, "d", "DDPG", [0], [0.2], hp={"clip_q_target": 0.0})  # another setting
    points, notes = pool(load_runs([tmp_path]))
    by_label = {p.text(): p for p in points}
    assert set(by_label) == {"DDPG", "DDPG, clip_q_target=0"}
    assert by_label["DDPG"].scores("training") == {0: 0.8, 1: 0.6, 2: 0.7, 3: 0.5}
    assert by_label["DDPG"].scores("validation")[0] == pytest.approx(0.7)
    assert any("seed 3" in n and "counted once" in n for n in notes)


def test_a_repeated_population_is_one_note_naming_its_seeds(tmp_path):
    write_run(tmp_path, "a", "DDPG", [0, 1, 2, 3], [0.8, 0.6, 0.7, 0.5])
    write_run(tmp_path, "b", "DDPG", [0, 1, 2, 3], [0.1, 0.1, 0.1, 0.1])
    write_run(tmp_path, "c", "DDPG", [0, 2], [0.1, 0.1])
    points, notes = pool(load_runs([tmp_path]))
    assert points[0].scores("training") == {0: 0.8, 1: 0.6, 2: 0.7, 3: 0.5}
    assert len(notes) == 2
    assert "seeds 0-3 of DDPG" in notes[0] and notes[0].endswith("counted once")
    assert "seeds 0, 2 of DDPG" in notes[1]


def test_labels_name_the_learner_and_leave_out_what_a_type_does_not_read(tmp_path):
    write_run(tmp_path, "a", "LfD", [0], [0.8])
    write_run(tmp_path, "b", "LfD", [0], [0.7], algo="td3", policy_delay=2)
    ddpg = write_run(tmp_path, "c", "DDPG", [0], [0.6])
    summary = json.loads((ddpg / "run.json").read_text())
    for row in summary["agents"]:  # a study's per-point value of a baseline's setting
        row.update(demo_episodes=100.0, random_episodes=20.0)
    (ddpg / "run.json").write_text(json.dumps(summary))
    points, _ = pool(load_runs([tmp_path]))
    assert {p.text() for p in points} == {"LfD", "LfD, algo=td3, policy_delay=2", "DDPG"}


def test_unfinished_runs_are_left_out_with_a_note(tmp_path):
    write_run(tmp_path, "a", "DDPG", [0], [0.8])
    write_run(tmp_path, "b", "DDPG", [1], [0.7], status="interrupted")
    runset = load_runs([tmp_path])
    assert [r.path.name for r in runset.runs] == ["a"]
    assert "status 'interrupted', left out" in runset.notes[0]


def _interrupted_after_evaluation(root, name, outcome):
    """A run stopped while writing its final outputs: eval.json written, run.json not."""
    run = write_run(root, name, "DDPG", [0, 1], [0.8, 0.6], episodes=3, outcome=outcome)
    summary = json.loads((run / "run.json").read_text())
    (run / "eval.json").write_text(json.dumps(summary.pop("evaluation")))
    summary["status"] = "interrupted"
    (run / "run.json").write_text(json.dumps(summary))
    return run


def test_a_run_stopped_after_its_final_evaluation_is_read_as_finished(tmp_path):
    _interrupted_after_evaluation(tmp_path, "a", [[1, 2, 3], [3, 2, 1]])
    runset = load_runs([tmp_path])
    assert [r.path.name for r in runset.runs] == ["a"]
    assert "stopped after its final evaluation was written" in runset.notes[0]
    (point,), _ = pool(runset)
    assert point.scores("training") == {0: 0.8, 1: 0.6}


def test_a_run_stopped_before_its_agents_finished_is_left_out(tmp_path):
    _interrupted_after_evaluation(tmp_path, "a", [[1, 2, 3], [3, 2, 0]])  # an episode not played
    run = write_run(tmp_path, "b", "DDPG", [2], [0.5], episodes=3, outcome=[[1, 1, 1]])
    summary = json.loads((run / "run.json").read_text())
    (run / "run.json").write_text(json.dumps({**summary, "status": "interrupted"}))  # no eval
    runset = load_runs([tmp_path])
    assert runset.runs == []
    assert all("status 'interrupted', left out" in n for n in runset.notes)


def test_runs_on_other_evaluation_episodes_are_refused(tmp_path):
    write_run(tmp_path, "a", "DDPG", [0], [0.8], eval_seed=0)
    write_run(tmp_path, "b", "DDPG", [1], [0.7], eval_seed=8)
    with pytest.raises(ValueError, match="different episodes .* no seed is common to all"):
        load_runs([tmp_path])


def test_a_re_evaluation_both_runs_have_is_taken(tmp_path):
    write_run(tmp_path, "a", "DDPG", [0], [0.8], eval_seed=0, snapshots={200: [0.3]})
    write_run(tmp_path, "b", "DDPG", [1], [0.7], eval_seed=8, extra_evals={0: [0.4]})
    runset = load_runs([tmp_path])
    assert {r.path.name: r.eval_seed for r in runset.runs} == {"a": 0, "b": 0}
    (point,) = [p for p in pool(runset)[0] if not p.snapshot]
    assert point.scores("training") == {0: 0.8, 1: 0.4}
    missing = r"not evaluated on eval seed 8: run advisor-jax reevaluate .*a --eval-seed 8"
    with pytest.raises(ValueError, match=missing):
        load_runs([tmp_path], eval_seed=8)


def test_episode_counts_and_arenas_must_match_too(tmp_path):
    write_run(tmp_path, "a", "DDPG", [0], [0.8], eval_episodes=50)
    write_run(tmp_path, "b", "DDPG", [1], [0.7], eval_episodes=100)
    with pytest.raises(ValueError, match="evaluated on different episodes"):
        load_runs([tmp_path])
    write_run(tmp_path / "p", "c", "DDPG", [2], [0.7], preset_name="physical",
              arenas=("physical",), eval_episodes=100)  # fmt: skip
    assert len(load_runs([tmp_path / "p"]).runs) == 1  # another training arena: its own set


def test_kept_actors_are_points_at_their_budget(tmp_path):
    write_run(tmp_path, "a", "ATD3+AfDP", [0, 1], [0.8, 0.9], snapshots={200: [0.5, 0.6]})
    points, _ = pool(load_runs([tmp_path]))
    budgets = {p.budget: p for p in points}
    assert set(budgets) == {200, 500}
    assert budgets[200].snapshot and not budgets[500].snapshot
    assert budgets[200].scores("training") == {0: 0.5, 1: 0.6}


def test_a_static_setting_is_part_of_the_point(tmp_path):
    write_run(tmp_path, "a", "ATD3+AfDP", [0], [0.8])
    write_run(tmp_path, "b", "ATD3+AfDP", [0], [0.7], policy_delay=2, precision="bf16")
    points, _ = pool(load_runs([tmp_path]))
    assert sorted(p.text() for p in points) == [
        "ATD3+AfDP", "ATD3+AfDP, policy_delay=2, precision=bf16"
    ]  # fmt: skip


def test_compact_run_keeps_what_the_loader_reads(tmp_path):
    run = write_run(tmp_path, "in", "DDPG", [0, 1], [0.8, 0.6], outcome=[[1, 2, 1], [2, 2, 3]])
    (run / "episodes.csv").write_text("x\n")
    (run / "command.json").write_text(json.dumps({"command": "c", "machine": "somewhere"}))
    compact_run(run, tmp_path / "out" / "a")
    kept = sorted(p.name for p in (tmp_path / "out" / "a").iterdir())
    assert kept == ["command.json", "metrics.npz", "run.json"]
    assert json.loads((tmp_path / "out" / "a" / "command.json").read_text()) == {"command": "c"}
    metrics = np.load(tmp_path / "out" / "a" / "metrics.npz")
    assert metrics["outcome"].dtype == np.int8 and metrics["length"].dtype == np.int16
    assert metrics["reward_per_step"].dtype == np.float16
    np.testing.assert_array_equal(metrics["outcome"], [[1, 2, 1], [2, 2, 3]])
    (point,) = pool(load_runs([tmp_path / "out"]))[0]
    np.testing.assert_array_equal(point.episodes("outcome"), [[1, 2, 1], [2, 2, 3]])
    assert "episode_return" not in metrics  # reward per step × length gives it back
    original = np.load(run / "metrics.npz")
    np.testing.assert_allclose(
        point.seeds[0].run.metrics()["episode_return"], original["episode_return"], rtol=1e-3
    )


def test_compact_run_writes_measured_rates_in_float32_digits_and_settings_as_they_are(tmp_path):
    """Evaluations (float32 rates) keep float32's shortest digits, the same float32 values;
    a run's settings are the user's float64 values and stay exact."""
    success = [float(np.float32(0.81)), float(np.float32(0.346))]  # 0.8100000619888306, ...
    run = write_run(tmp_path, "in", "DDPG", [0, 1], success)
    record = json.loads((run / "run.json").read_text())
    record["agents"][0]["beta"] = 1 / 3
    (run / "run.json").write_text(json.dumps(record))
    (run / "eval_seed8.json").write_text(json.dumps({"training": {"success": success}}))
    (run / "eval.json").write_text(json.dumps(record["evaluation"]))
    compact_run(run, tmp_path / "out" / "a")
    kept = json.loads((tmp_path / "out" / "a" / "run.json").read_text())
    assert kept["agents"][0]["beta"] == 1 / 3
    assert kept["evaluation"]["training"]["success"] == [0.81, 0.346]
    assert json.loads((tmp_path / "out" / "a" / "eval_seed8.json").read_text()) == {
        "training": {"success": [0.81, 0.346]}
    }
    assert not (tmp_path / "out" / "a" / "eval.json").exists()  # run.json holds it
    assert np.float32(0.81) == np.float32(success[0]) and 0.81 != success[0]


def test_a_kept_copy_reads_as_the_run_itself(tmp_path):
    """The loader reads evaluations as float32's shortest digits, so a compact copy and the
    run it came from give the same scores to the last bit (no spurious win between 0.86
    and 0.8600000143051147 in a seed-by-seed comparison)."""
    success = [float(np.float32(0.86)), float(np.float32(0.7))]
    run = write_run(tmp_path / "raw", "a", "DDPG", [0, 1], success)
    compact_run(run, tmp_path / "kept" / "a")
    (raw,), _ = pool(load_runs([tmp_path / "raw"]))
    (kept,), _ = pool(load_runs([tmp_path / "kept"]))
    assert raw.scores("training") == kept.scores("training") == {0: 0.86, 1: 0.7}


def test_compact_run_leaves_default_hyperparameters_out_and_the_points_stay(tmp_path):
    """A kept run.json's rows keep only hyperparameters away from ``HParams``' default (and
    no identity): the loader reads the same settings, so the same points."""
    from advisor_jax.agent.hparams import HPARAM_DEFAULTS

    run = write_run(tmp_path / "full", "a", "ATD3+AfDP", [0, 1], [0.8, 0.6])
    record = json.loads((run / "run.json").read_text())
    record["agents"][1]["beta"] = 0.3  # one setting away from the default
    record["identity"] = {"config_sha256": "x", "seeds": [0, 1]}
    (run / "run.json").write_text(json.dumps(record))
    compact_run(run, tmp_path / "kept" / "a")
    kept = json.loads((tmp_path / "kept" / "a" / "run.json").read_text())
    assert "identity" not in kept
    assert kept["agents"][1]["beta"] == 0.3 and kept["agents"][1]["seed"] == 1
    assert not any(k in HPARAM_DEFAULTS and v == HPARAM_DEFAULTS[k]
                   for row in kept["agents"] for k, v in row.items())  # fmt: skip
    full = {p.text(): p.settings for p in pool(load_runs([tmp_path / "full"]))[0]}
    compact = {p.text(): p.settings for p in pool(load_runs([tmp_path / "kept"]))[0]}
    assert full == compact and len(full) == 2
