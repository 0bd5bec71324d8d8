"""experiments/afp_collapse.py on a hand-made run directory: which agent collapsed, and
which diagnostic went wrong first, at which episode."""

from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[2] / "experiments"))

import afp_collapse  # noqa: E402

N_EPISODES, N_CHUNKS, LENGTH = 1000, 40, 50  # 50 steps per episode, 1000 steps per chunk


def _run_dir(tmp_path: Path) -> Path:
    """Agent 0 learns; agent 1 saturates from chunk 10 (episode 220), its critic blows up
    from chunk 20 and its Q passes the return bound (17.5 at γ = 0.9) from chunk 25; it then
    only times out and fails its evaluation."""
    run = tmp_path / "run"
    run.mkdir()
    agents = [
        dict(index=i, seed=i, gamma=0.9, beta=3.0, beta_normalize=0.0, clip_actor_target=0.0)
        for i in range(2)
    ]
    (run / "run.json").write_text(
        json.dumps(dict(agent="ATD3+AfDP", agents=agents, device="cpu", created="2026-11-23"))
    )
    outcome = np.ones((2, N_EPISODES), np.int32)
    outcome[1, 100:] = 3  # timeouts from episode 100 on
    saturated = np.full((2, N_CHUNKS), 0.05)
    saturated[1, 10:] = 0.8
    critic = np.full((2, N_CHUNKS), 0.04)
    critic[:, :2] = 5.0  # the first updates' transient: no blow-up
    critic[1, 20:] = 50.0
    q = np.full((2, N_CHUNKS), 2.0)
    q[0, 30] = 17.0  # below the bound: not counted
    q[1, 25:] = 120.0
    np.savez(
        run / "metrics.npz",
        outcome=outcome,
        length=np.full((2, N_EPISODES), LENGTH, np.int32),
        **{
            "log/step": 1000 * np.arange(1, N_CHUNKS + 1),
            "log/diag/saturated": saturated,
            "log/loss/critic": critic,
            "log/diag/step": np.full((2, N_CHUNKS), 2.0),
            "log/q/mean": q,
        },
    )
    evaluation = dict(success=[0.9, 0.1])
    (run / "eval.json").write_text(json.dumps(dict(training=evaluation, validation=evaluation)))
    return run


def test_the_collapsed_agent_and_what_went_wrong_first(tmp_path):
    args = argparse.Namespace(advisor_level=0.5, saturated=0.5, blowup=100.0)
    good, bad = afp_collapse.analyse_run(_run_dir(tmp_path), args)
    assert not good["collapsed"] and bad["collapsed"]
    assert good["saturation_at"] is None and good["critic_blowup_at"] is None
    # Chunk c ends after 1000 (c + 1) steps = 20 (c + 1) episodes of 50 steps.
    assert bad["saturation_at"] == 20 * 11
    assert bad["critic_blowup_at"] == 20 * 21
    assert bad["collapse_at"] == 100 and good["collapse_at"] is None
    assert good["q_over_bound_at"] is None and bad["q_over_bound_at"] == 20 * 26
    assert bad["max_q"] == 120.0 and bad["q_bound"] == 17.5
    assert bad["clip_q_target"] == 0.0  # an older run without the field reads as off
    assert bad["blocks"][:2] == [1.0, 1.0] and set(bad["blocks"][2:]) == {0.0}

    (group,) = afp_collapse.summarise([good, bad])
    assert group["collapsed"] == 1 and group["saturated"] == 1 and group["critic_blowup"] == 1
    assert group["q_over_bound"] == 1
    assert group["setting"] == "ATD3+AfDP β=3 literal"
    assert group["min_seed_training"] == 0.1 and group["seeds"] == [0, 1]


def test_a_slow_start_is_not_a_collapse():
    assert afp_collapse.collapse_episode([0.1, 0.2, 0.6, 0.8]) is None
    assert afp_collapse.collapse_episode([0.1, 0.6, 0.2, 0.8]) == 100


def test_labels_name_what_the_agent_type_uses():
    assert afp_collapse.label(("DDPG", 1.0, 1.0, 1.0, 0.0)) == "DDPG"  # no Eq. 2: β unused
    assert afp_collapse.label(("TD3", 1.0, 0.0, 0.0, 1.0)) == "TD3 (Q̂ clipped)"
    assert afp_collapse.label(("ADDPG", 1.0, 1.0, 1.0, 0.0)) == "ADDPG β=1 scale-free, Â clipped"
    assert (
        afp_collapse.label(("ADDPG+AfD", 0.3, 1.0, 1.0, 1.0))
        == "ADDPG+AfD β=0.3 scale-free, Â clipped, Q̂ clipped"
    )
