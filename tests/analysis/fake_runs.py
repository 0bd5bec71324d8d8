"""Hand-made run directories, as ``advisor-jax train`` writes them, for the loader's tests."""

from __future__ import annotations

import dataclasses
import json
from pathlib import Path

import numpy as np

from advisor_jax.agent.config import preset
from advisor_jax.agent.settings import flat_items, replace_flat


def write_run(root: Path, name: str, agent: str, seeds, success, *, preset_name="stable",
              hp=None, episodes=None, eval_seed=0, eval_episodes=50,
              arenas=("training", "validation"), status="finished", extra_evals=None,
              snapshots=None, outcome=None, advisor="rule", advisor_success=None,
              **static):  # fmt: skip
    """A finished run of ``agent`` (one agent per seed) whose agents scored ``success`` (per
    seed) in the first arena and ``success - 0.1`` in the others; its advisor alone
    ``advisor_success`` (per seed, ``--eval-advisor``) likewise."""
    cfg, base = preset(preset_name, agent)
    cfg = dataclasses.replace(cfg, agent=dataclasses.replace(cfg.agent, **static),
                              episodes=episodes or cfg.episodes, advisor=advisor)  # fmt: skip
    base = replace_flat(base, **(hp or {}))
    rows = [{"seed": s, "index": i, **{n: float(v) for n, v in flat_items(base).items()}}
            for i, s in enumerate(seeds)]  # fmt: skip

    def evaluation(values):
        return {a: {"success": [v - 0.1 * (k > 0) for v in values],
                    "collision": [0.1] * len(values), "timeout": [0.0] * len(values),
                    "collision_speed": [0.5] * len(values),
                    "collision_speed_sd": [0.1] * len(values), "episodes": eval_episodes}
                for k, a in enumerate(arenas)}  # fmt: skip

    summary = {
        "created": "2026-11-26T00:00:00+00:00", "device": "cpu", "agent": agent,
        "config": json.loads(json.dumps(dataclasses.asdict(cfg))), "preset": preset_name,
        "grid": {}, "eval_seed": eval_seed, "agents": rows, "status": status,
        "evaluation": evaluation(success),
        "command": f"advisor-jax train --agent {agent}",
        "env_steps_per_agent": [100] * len(rows), "train_seconds": 1.0,
    }  # fmt: skip
    if advisor_success is not None:
        summary["advisor_evaluation"] = evaluation(advisor_success)
    if snapshots:
        summary["evaluation_at_episode"] = {str(n): evaluation(v) for n, v in snapshots.items()}
    run = root / name
    run.mkdir(parents=True)
    (run / "run.json").write_text(json.dumps(summary))
    for seed, values in (extra_evals or {}).items():
        (run / f"eval_seed{seed}.json").write_text(json.dumps(evaluation(values)))
    if outcome is not None:
        n = len(seeds)
        per_step = np.linspace(-1.0, 2.0, np.size(outcome)).reshape(np.shape(outcome))
        np.savez(run / "metrics.npz", outcome=np.asarray(outcome, np.int32),
                 length=np.full_like(np.asarray(outcome), 10), reward_per_step=per_step,
                 episode_return=10 * per_step,
                 env_steps=np.full(n, 10 * np.shape(outcome)[1]))  # fmt: skip
    return run
