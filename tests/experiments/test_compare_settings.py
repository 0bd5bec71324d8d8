"""experiments/compare_settings.py on hand-made run directories: the same agent types at two
settings, paired by seed, with the critic's Q against the return bound."""

from __future__ import annotations

import json
import sys
from pathlib import Path

import numpy as np
import pytest

sys.path.insert(0, str(Path(__file__).resolve().parents[2] / "experiments"))

import compare_settings  # noqa: E402

from advisor_jax.agent.config import preset  # noqa: E402
from advisor_jax.training.population import build_population  # noqa: E402

N_EPISODES, N_CHUNKS, LENGTH = 100, 10, 50  # 50 steps per episode, 1000 steps per chunk


def _run(root: Path, agent: str, clip_q: float, success: list[float], q_peak: list[float]):
    """A finished run of ``agent`` (preset ``quick``) with ``clip_q_target = clip_q``,
    seeds 0..n-1; agent i scores ``success[i]`` in training (validation: the same minus
    0.1) and its batch-mean Q is 2 until chunk 5, then ``q_peak[i]``."""
    _, hp = preset("quick", agent)
    seeds = list(range(len(success)))
    _, agents = build_population(hp, {"clip_q_target": [clip_q]}, seeds)
    n = len(agents)
    run = root / agent.replace("+", "_")
    run.mkdir(parents=True)
    evaluation = {
        arena: {
            "success": [s - shift for s in success],
            "collision": [0.0] * n,
            "timeout": [0.0] * n,
            "collision_speed": [0.1] * n,
            "episodes": 10,
        }
        for arena, shift in (("training", 0.0), ("validation", 0.1))
    }
    summary = dict(
        agent=agent,
        preset="quick",
        device=f"gpu-{clip_q:g}",
        created="2026-11-23T12:00",
        config={"episodes": N_EPISODES},
        grid={},
        agents=agents,
        status="finished",
        diverged=[],
        evaluation=evaluation,
    )
    (run / "run.json").write_text(json.dumps(summary))
    (run / "eval.json").write_text(json.dumps(evaluation))
    (run / "command.json").write_text(json.dumps({"command": f"train {agent} clip {clip_q:g}"}))
    q = np.full((n, N_CHUNKS), 2.0)
    q[:, 5:] = np.asarray(q_peak)[:, None]
    np.savez(
        run / "metrics.npz",
        outcome=np.ones((n, N_EPISODES), np.int32),
        length=np.full((n, N_EPISODES), LENGTH, np.int32),
        **{
            "log/step": 1000 * np.arange(1, N_CHUNKS + 1),
            "log/diag/saturated": np.zeros((n, N_CHUNKS)),
            "log/loss/critic": np.full((n, N_CHUNKS), 0.1),
            "log/diag/step": np.full((n, N_CHUNKS), 0.5),
            "log/q/mean": q,
        },
    )


@pytest.fixture
def roots(tmp_path):
    clipped, plain = tmp_path / "clipped", tmp_path / "plain"
    _run(clipped, "ADDPG", 1.0, [0.8, 0.9, 0.7, 0.8], [3.0, 2.5, 2.0, 2.0])
    _run(plain, "ADDPG", 0.0, [0.6, 0.8, 0.4, 0.6], [100.0, 2.0, 2.0, 20.0])
    _run(plain, "DDPG", 0.0, [0.6, 0.6, 0.6, 0.6], [2.0, 2.0, 2.0, 2.0])  # no partner
    return clipped, plain


def test_pairs_by_seed_and_counts_the_overestimating_seeds(roots):
    """ADDPG, clipped − plain = (+20, +10, +30, +20) points: mean 20, sd 8.165, t_0.975,3 =
    3.182, half-width 3.182 · 8.165 / 2 = 12.99: holds. DDPG has no clipped run: left out."""
    (row,) = compare_settings.compare(*roots, level=0.5)
    assert row["agent"] == "ADDPG"
    assert row["difference"] == "clip_q_target=1 vs 0 (the preset's)"
    training = row["paired"]["training"]
    assert training["seeds"] == 4 and training["verdict"] == "holds"
    assert training["mean"] == pytest.approx(20.0) and training["half"] == pytest.approx(
        12.99, abs=0.01
    )
    treated, control = row["treatment"], row["control"]
    assert treated["training"]["mean"] == pytest.approx(80.0)
    assert control["validation"]["mean"] == pytest.approx(50.0)
    assert (treated["worst"], control["worst"]) == pytest.approx((70.0, 40.0))
    assert (treated["below_advisor"], control["below_advisor"]) == (0, 1)  # 0.4 < 0.5
    assert (treated["q_over_bound"], control["q_over_bound"]) == (0, 2)  # 100 and 20 > 17.5
    assert (treated["max_q"], control["max_q"]) == (3.0, 100.0)
    assert treated["q_bound"] == pytest.approx(17.5)


def test_writes_the_report_table_figure_and_json(roots, tmp_path, monkeypatch):
    out = tmp_path / "out"
    argv = ["compare_settings.py", *map(str, roots), "--name", "clip", "--out", str(out)]
    monkeypatch.setattr(sys, "argv", argv)
    compare_settings.main()
    text = (out / "clip.md").read_text()
    assert "Settings that differ: clip_q_target=1 vs 0 (the preset's)" in text
    assert "| ADDPG | 4 | 80.0 ± " in text and "20.0 ± 13.0 (holds)" in text
    assert "gpu-0 (2026-11-23)" in text and "gpu-1 (2026-11-23)" in text
    assert "`train ADDPG clip 1`" in text and "`train ADDPG clip 0`" in text
    record = json.loads((out / "clip.json").read_text())
    assert [a["agent"] for a in record["agents"]] == ["ADDPG"]
    assert (out / "clip.png").stat().st_size > 0


def test_no_common_agent_type_is_an_error(roots, tmp_path, monkeypatch):
    empty = tmp_path / "empty"
    empty.mkdir()
    monkeypatch.setattr(sys, "argv", ["compare_settings.py", str(roots[0]), str(empty)])
    with pytest.raises(SystemExit, match="no agent type finished under both"):
        compare_settings.main()
