"""What a user meets around a finished run (issue 38): ``evaluate RUN:AGENT`` repeats the
run's eval.json, its errors name what was typed, the closing line names the files that
exist, the summary table says what its ± is, and the run's plots have labelled axes."""

from __future__ import annotations

import json

import numpy as np
import pytest
from rich.console import Console

from advisor_jax import stats
from advisor_jax.cli.train import written
from advisor_jax.training import plots, reporting
from tests.cli.test_main import _run as _cli
from tests.training.conftest import TINY, train_tiny

EVAL = 8


@pytest.fixture(scope="module")
def evaluated_run(tmp_path_factory, tiny_functions):
    """A TINY run of the session's 5 seeds (its compiled program: another agent count would
    compile again) scored on eval seed 4's episodes in the training arena."""
    out = tmp_path_factory.mktemp("evaluated")
    train_tiny(out, tiny_functions, eval_episodes=EVAL, eval_arenas=("training",), eval_seed=4)
    return out


def test_evaluate_repeats_eval_json_by_default(evaluated_run, capsys):
    saved = json.loads((evaluated_run / "eval.json").read_text())["training"]
    for agent in range(3):
        code, out, err = _cli(["evaluate", "--policy", f"{evaluated_run}:{agent}", "--json"],
                              capsys)  # fmt: skip
        result = json.loads(out)
        assert code == 0 and result["eval_seed"] == 4 and result["episodes"] == EVAL
        assert result["success_rate"] == pytest.approx(saved["success"][agent], abs=1e-6)
        assert result["collision_rate"] == pytest.approx(saved["collision"][agent], abs=1e-6)
        assert "the episodes of" in err and "eval seed 4" in err


@pytest.mark.parametrize(
    ("policy", "message"),
    [
        ("{run}:7", "--policy {run}:7: agent 7 is out of range: {run} has 5 agents (0-4)"),
        ("{run}/nope:0", "--policy {run}/nope:0: {run}/nope does not exist"),
        ("{run}/params", "is neither a training run (no run.json) nor an export"),
    ],
)
def test_evaluate_errors_name_what_was_typed(evaluated_run, capsys, policy, message):
    policy, message = (x.replace("{run}", str(evaluated_run)) for x in (policy, message))
    code, _, err = _cli(["evaluate", "--policy", policy], capsys)
    assert code == 2 and message in " ".join(err.split()) and "--agent" not in err


def test_the_closing_line_names_the_files_that_exist(evaluated_run, tmp_path):
    line = written(evaluated_run)
    for name in ("run.json", "eval.json", "train_log.jsonl", "params/", "learning_curve.png"):
        assert name in line
    (tmp_path / "run.json").write_text("{}")  # a run with --eval-episodes 0, say
    assert written(tmp_path) == f"results in {tmp_path}/ (run.json)"


def test_the_summary_table_says_what_its_interval_is():
    agents = [{"index": i, "seed": i} for i in range(2)]
    outcome = np.array([[1, 1, 2, 1], [2, 1, 1, 1]], np.int32)
    metrics = {"outcome": outcome, "diverged": np.zeros(2, bool)}
    console = Console(record=True, width=120)
    evaluation = {"training": {"success": [0.5, 0.6]}}
    summary = {"agent": "DDPG", "agents": agents, "evaluation": evaluation}
    reporting.print_summary(console, summary, metrics, {})
    text = console.export_text()
    assert "DDPG: 2 agents" in text and "55.0 % (n=2)" in text and "±" not in text.split("\n")[4]
    assert "95 % t interval (none below 3 seeds)" in " ".join(text.split())
    console = Console(record=True, width=120)
    reporting.print_summary(console, {**summary, "agents": agents[:1]}, metrics, {})
    assert "DDPG: 1 agent " in console.export_text()  # not "1 agents"


def test_the_summary_also_gives_the_interval_for_new_evaluation_episodes():
    """Three agents that fail the same two of four episodes: their seeds agree (± 0), but a
    new set of episodes could fall anywhere: the seeds-and-episodes interval says so."""
    agents = [{"index": i, "seed": i} for i in range(3)]
    metrics = {"outcome": np.ones((3, 4), np.int32), "diverged": np.zeros(3, bool)}
    evaluation = {"training": {"success": [0.5] * 3, "outcomes": ["1122"] * 3, "episodes": 4}}
    summary = {"agent": "DDPG", "agents": agents, "evaluation": evaluation}
    console = Console(record=True, width=200)
    reporting.print_summary(console, summary, metrics, {})
    text = " ".join(console.export_text().split())
    wide = stats.t_interval([1.0, 1.0, 0.0, 0.0])  # the four episodes are the sample
    assert "50.0 ± 0.0 %" in text
    assert (
        f"new evaluation episodes alike (stats.seeds_and_episodes_interval): training "
        f"50.0 ± {100 * wide.half:.1f} %" in text
    )
    del evaluation["training"]["outcomes"]  # a run recorded before outcomes: no such line
    console = Console(record=True, width=200)
    reporting.print_summary(console, summary, metrics, {})
    assert "new evaluation episodes" not in console.export_text()


def test_the_runs_plots_label_their_axes(evaluated_run, monkeypatch):
    figures = []
    monkeypatch.setattr(plots, "save_png", lambda fig, path: figures.append(fig))
    metrics = dict(np.load(evaluated_run / "metrics.npz"))
    agents = json.loads((evaluated_run / "run.json").read_text())["agents"]
    plots.plot_learning_curves(evaluated_run / "x.png", metrics, agents, {}, name="DDPG",
                               arena="training")  # fmt: skip
    series = reporting.read_training_log(evaluated_run / "train_log.jsonl", len(agents))
    plots.plot_diagnostics(evaluated_run / "y.png", series, agents, {}, name="DDPG",
                           arena="training")  # fmt: skip
    assert len(figures) == 2
    for fig in figures:
        for ax in fig.axes:
            if ax.get_visible() and ax.lines:
                assert ax.get_xlabel() and ax.get_ylabel(), ax.get_title()
    fig = figures[0]  # episodes are whole numbers (a grid run of few episodes showed 1.5)
    fig.canvas.draw()
    ticks = [t.get_text() for t in fig.axes[0].get_xticklabels() if t.get_text()]
    assert ticks and all(t.lstrip("−-").isdigit() for t in ticks), ticks
    assert TINY.episodes < 20  # the case that drew fractional ticks
