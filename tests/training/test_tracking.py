"""--tensorboard / --wandb (training/tracking.py): every chunk's population means and each
agent's values, read back from the event files; W&B imported only when asked."""

from __future__ import annotations

import json
import sys
import types

import pytest

from advisor_jax.training.tracking import make_tracker
from tests.training.conftest import RUN_SEEDS, train_tiny
from tests.training.event_files import scalars


def test_tensorboard_holds_every_chunk_of_every_agent(tmp_path, tiny_functions):
    out, logdir = tmp_path / "run", tmp_path / "tb"
    tracker = make_tracker(str(logdir), None, "tiny", {})
    assert "wandb" not in sys.modules  # not imported unless asked
    train_tiny(out, tiny_functions, tracker=tracker)
    tracker.close()
    rows = [json.loads(line) for line in (out / "train_log.jsonl").read_text().splitlines()]
    tags = scalars(logdir)
    steps = [row["step"] for row in rows]
    assert [s for s, _ in tags["progress/episodes_mean"]] == steps
    for i in range(len(RUN_SEEDS)):
        values = tags[f"agent{i}/loss/critic"]
        expected = [(r["step"], r["per_agent"]["loss/critic"][i]) for r in rows
                    if r["per_agent"]["loss/critic"][i] is not None]  # fmt: skip
        assert [s for s, _ in values] == [s for s, _ in expected]
        assert [v for _, v in values] == pytest.approx([v for _, v in expected], rel=1e-6)
    population = dict(tags["population/loss/critic"])
    assert population[rows[-1]["step"]] == pytest.approx(rows[-1]["loss/critic"], rel=1e-6)


def test_wandb_gets_the_samescalars(monkeypatch):
    logged = []

    class Run:
        def define_metric(self, *args, **kwargs):
            pass

        def log(self, values):
            logged.append(values)

        def finish(self):
            logged.append("finished")

    fake = types.SimpleNamespace(init=lambda **kw: Run())
    monkeypatch.setitem(sys.modules, "wandb", fake)
    tracker = make_tracker(None, "proj", "run1", {"agent": "DDPG"})
    tracker.log_chunk({"step": 100, "seconds": 1.0, "episodes_mean": 2.0, "loss/critic": 0.5,
                       "per_agent": {"loss/critic": [0.4, None]}})  # fmt: skip
    tracker.close()
    assert logged[0] == {"progress/episodes_mean": 2.0, "population/loss/critic": 0.5,
                         "agent0/loss/critic": 0.4, "env_step": 100}  # fmt: skip
    assert logged[-1] == "finished"


def test_wandb_missing_is_one_line(monkeypatch):
    monkeypatch.setitem(sys.modules, "wandb", None)  # import fails
    with pytest.raises(ValueError, match="--wandb proj needs the wandb package"):
        make_tracker(None, "proj", "run1", {})
