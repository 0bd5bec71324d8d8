"""experiments/eval_set_variance.py: a run's success on other sets of evaluation episodes."""

from __future__ import annotations

import json

import numpy as np
import pytest

from advisor_jax.evaluation.evaluate import success_table
from advisor_jax.training.run_directory import reevaluate
from tests.experiments.scripts import load_script

eval_set_variance = load_script("eval_set_variance")


def test_each_set_is_the_runs_reevaluation_on_its_seed_and_the_summary_follows(
    straight_run, tmp_path
):
    out = tmp_path / "out"
    argv = [str(straight_run), "--out", str(out), "--episodes", "4", "--sets", "3",
            "--first", "7", "--reference-episodes", "8", "--reference-seed", "99"]  # fmt: skip
    record = eval_set_variance.main(argv)
    assert json.loads((out / "eval_set_variance.json").read_text()) == record
    assert record["set_eval_seeds"] == [7, 8, 9] and record["own_episodes"] is None
    training = record["arenas"]["training"]
    for k, seed in enumerate(record["set_eval_seeds"]):  # what `advisor-jax reevaluate` scores
        again = reevaluate(straight_run, seed, 4, ("training",))["training"]["success"]
        assert training["set_means"][k] == round(100 * float(np.mean(again)), 2)
    reference = reevaluate(straight_run, 99, 8, ("training",))["training"]["success"]
    assert training["reference_mean"] == round(100 * float(np.mean(reference)), 2)
    means = np.array(training["set_means"])
    assert training["set_sd"] == round(float(means.std(ddof=1)), 2)
    assert training["set_range"] == [means.min(), means.max()]
    assert 0 <= training["coverage"] <= 1 and "own_offset" not in training
    assert 0 <= training["coverage_seeds_and_episodes"] <= 1
    assert training["mean_half_width_seeds_and_episodes"] >= 0
    assert "sets whose interval holds" in (out / "eval_set_variance.md").read_text()


def test_outcomes_give_each_agents_success_and_none_for_a_diverged_one(straight_run):
    scores = reevaluate(straight_run, 3, 6, ("training",))["training"]
    table = success_table(scores)
    assert table.shape == (len(scores["success"]), 6)
    assert list(table.mean(axis=1)) == pytest.approx(scores["success"])
    assert all(set(row) <= set("123") and len(row) == 6 for row in scores["outcomes"])
    scores = {**scores, "outcomes": [None, *scores["outcomes"][1:]]}
    assert np.isnan(success_table(scores)[0]).all()
    assert success_table(scores, [1]).shape == (1, 6)


@pytest.mark.parametrize(
    ("extra", "message"),
    [(["--sets", "1"], "at least 2 sets"), (["--reference-seed", "2"], "one of the sets")],
)
def test_bad_options_are_named(straight_run, tmp_path, capsys, extra, message):
    with pytest.raises(SystemExit):
        eval_set_variance.main([str(straight_run), "--out", str(tmp_path), *extra])
    assert message in capsys.readouterr().err
