"""experiments/precision_study.py on hand-made run directories: seeds are paired, each on
the evaluation episodes its fp32 run used, and the difference is bf16 - fp32."""

from __future__ import annotations

import json
import sys
from pathlib import Path

import numpy as np
import pytest

sys.path.insert(0, str(Path(__file__).resolve().parents[2] / "experiments"))

import precision_study  # noqa: E402


def _run(root: Path, name: str, seeds, betas, evals: dict[int, list[float]], eval_seed=None):
    """A run of agents (seed, beta) with success lists per eval seed (training arena =
    validation arena - 0.1)."""
    run = root / name
    run.mkdir()
    agents = [
        dict(index=i, seed=s, beta=b) for i, (s, b) in enumerate(zip(seeds, betas, strict=True))
    ]
    summary = dict(agents=agents, **({} if eval_seed is None else {"eval_seed": eval_seed}))
    (run / "run.json").write_text(json.dumps(summary))
    own = seeds[0] if eval_seed is None else eval_seed
    for e, success in evals.items():
        ev = {"training": {"success": success},
              "validation": {"success": [x + 0.1 for x in success]}}  # fmt: skip
        (run / ("eval.json" if e == own else f"eval_seed{e}.json")).write_text(json.dumps(ev))


def test_pairs_seeds_on_their_fp32_evaluation_episodes(tmp_path):
    # fp32: seeds 0, 1 (eval seed 0; a grid over beta, only beta = 1 taken), seeds 8, 9
    # (eval seed 8). bf16: seeds 0, 1, 8, 9 in one run on eval seed 0, re-evaluated on 8.
    _run(tmp_path, "a", [0, 1, 0, 1], [0.3, 0.3, 1.0, 1.0], {0: [0.1, 0.1, 0.8, 0.6]})
    _run(tmp_path, "b", [8, 9], [1.0, 1.0], {8: [0.7, 0.5]})
    _run(tmp_path, "c", [0, 1, 8, 9], [1.0] * 4,
         {0: [0.7, 0.6, 0.0, 0.0], 8: [0.0, 0.0, 0.6, 0.3]}, eval_seed=0)  # fmt: skip
    study = {"X": {"fp32": [("a", {"beta": 1.0}), ("b", {})], "bf16": [("c", {})]}}
    (row,) = precision_study.compare(study, tmp_path)
    assert row["seeds"] == [0, 1, 8, 9]
    np.testing.assert_allclose(row["training"]["fp32"], [0.8, 0.6, 0.7, 0.5])
    np.testing.assert_allclose(row["training"]["bf16"], [0.7, 0.6, 0.6, 0.3])
    np.testing.assert_allclose(row["validation"]["bf16"], [0.8, 0.7, 0.7, 0.4])
    mean, _ = row["training"]["difference_mean_ci"]
    assert mean == pytest.approx(np.mean([-0.1, 0.0, -0.1, -0.2]))
    assert row["training"]["collapsed"] == {"fp32": 0, "bf16": 1}


def test_a_missing_evaluation_names_the_command_that_makes_it(tmp_path):
    _run(tmp_path, "a", [8], [1.0], {8: [0.7]})
    _run(tmp_path, "c", [8], [1.0], {0: [0.5]}, eval_seed=0)
    study = {"X": {"fp32": [("a", {})], "bf16": [("c", {})]}}
    with pytest.raises(SystemExit, match="reevaluate.py .* --eval-seed 8"):
        precision_study.compare(study, tmp_path)
