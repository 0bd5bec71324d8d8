"""experiments/paired_runs.py: two runs of one setting, paired by seed, from kept run data."""

from __future__ import annotations

import json
import shutil

import numpy as np
import pytest

from tests.experiments.scripts import load_script

paired_runs = load_script("paired_runs")
RESULTS = paired_runs.Path(__file__).resolve().parents[2] / "results"
CONTROL = RESULTS / "table1_stable/run_data/ATD3_AfDP"
OTHER_AGENT = RESULTS / "table1_stable/run_data/DDPG"


def _success(run_dir, arena):
    summary = json.loads((run_dir / "run.json").read_text())
    seeds = [row["seed"] for row in summary["agents"]]
    return dict(zip(seeds, summary["evaluation"][arena]["success"], strict=True))


def test_the_difference_is_treatment_minus_control_seed_by_seed(tmp_path):
    # A treatment whose every seed succeeds 0.25 more often in the training arena than the
    # control and 0.1 less often in the validation arena.
    treatment = tmp_path / "treatment"
    shutil.copytree(CONTROL, treatment)
    summary = json.loads((treatment / "run.json").read_text())
    for arena, shift in (("training", 0.25), ("validation", -0.1)):
        summary["evaluation"][arena]["success"] = [
            s + shift for s in summary["evaluation"][arena]["success"]
        ]
    (treatment / "run.json").write_text(json.dumps(summary))

    out = tmp_path / "out"
    assert paired_runs.main([str(CONTROL), str(treatment), "--out", str(out)]) == 0
    record = json.loads((out / "paired.json").read_text())
    training, validation = record["arenas"]["training"], record["arenas"]["validation"]
    assert np.allclose(training["differences"], 0.25) and training["verdict"] == "holds"
    assert np.allclose(validation["differences"], -0.1) and validation["verdict"] == "reversed"
    assert training["seeds"] == sorted(_success(CONTROL, "training"))
    assert "experiments/paired_runs.py" in (out / "paired.md").read_text()


def test_runs_of_different_agents_are_refused(tmp_path):
    with pytest.raises(ValueError, match="agent or settings"):
        paired_runs.main([str(CONTROL), str(OTHER_AGENT), "--out", str(tmp_path)])


def test_seeds_whose_training_episodes_all_match_are_counted(tmp_path):
    # A copy of the control trained the same episodes; then one episode of one seed changes.
    treatment = tmp_path / "treatment"
    shutil.copytree(CONTROL, treatment)
    seeds = sorted(_success(CONTROL, "training"))
    points = (paired_runs.the_point(CONTROL, None), paired_runs.the_point(treatment, None))
    assert paired_runs.same_episodes(*points)["identical_seeds"] == seeds

    with np.load(treatment / "metrics.npz") as kept:
        metrics = dict(kept)
    metrics["length"] = metrics["length"].copy()
    metrics["length"][1, 7] += 1  # the second seed of run.json, episode 7
    np.savez_compressed(treatment / "metrics.npz", **metrics)
    second = json.loads((treatment / "run.json").read_text())["agents"][1]["seed"]

    out = tmp_path / "out"
    assert paired_runs.main([str(CONTROL), str(treatment), "--out", str(out)]) == 0
    episodes = json.loads((out / "paired.json").read_text())["same_episodes"]
    assert episodes["identical_seeds"] == [s for s in seeds if s != second]
    assert (
        f"every one equal: {len(seeds) - 1} of {len(seeds)} seeds"
        in (out / "paired.md").read_text()
    )


def test_seeds_whose_final_networks_match_are_counted_where_both_runs_record_them(tmp_path):
    sides = {name: tmp_path / name for name in ("control", "treatment")}
    for side in sides.values():
        shutil.copytree(CONTROL, side)
    out = tmp_path / "out"
    paired_runs.main([str(sides["control"]), str(sides["treatment"]), "--out", str(out)])
    assert "same_networks" not in json.loads((out / "paired.json").read_text())  # not recorded
    assert "Final networks" not in (out / "paired.md").read_text()

    seeds = [a["seed"] for a in json.loads((CONTROL / "run.json").read_text())["agents"]]
    for name, side in sides.items():
        summary = json.loads((side / "run.json").read_text())
        hashes = [f"{s:064x}" for s in seeds]
        if name == "treatment":
            hashes[2] = "f" * 64  # the third seed of run.json learned other bits
        (side / "run.json").write_text(json.dumps({**summary, "agent_params_sha256": hashes}))
    paired_runs.main([str(sides["control"]), str(sides["treatment"]), "--out", str(out)])
    networks = json.loads((out / "paired.json").read_text())["same_networks"]
    assert networks == dict(seeds=len(seeds), identical_seeds=sorted(set(seeds) - {seeds[2]}))
    assert (
        f"bit for bit equal: {len(seeds) - 1} of {len(seeds)} seeds"
        in (out / "paired.md").read_text()
    )
