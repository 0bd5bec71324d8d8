"""Reading back what ``run_training`` wrote: the config, the agents, one agent's actor."""

from __future__ import annotations

import json
from pathlib import Path

import jax
import numpy as np

from advisor_jax.agent.config import TrainConfig, train_config_from_dict
from advisor_jax.training import checkpoint


def load_run(run_dir: str | Path) -> tuple[TrainConfig, dict]:
    """(static config, run.json summary) of a training run directory."""
    run_dir = Path(run_dir)
    path = run_dir / "run.json"
    if not path.is_file():
        raise ValueError(f"{run_dir} is not a training run (no run.json)")
    try:
        summary = json.loads(path.read_text())
    except json.JSONDecodeError as e:
        raise ValueError(f"{path} is corrupt: {e}") from None
    return train_config_from_dict(summary.get("config", {})), summary


def load_actor(run_dir: str | Path, index: int) -> tuple[TrainConfig, dict, dict]:
    """(config, agent row of run.json, actor params) of agent ``index`` of a finished run."""
    run_dir = Path(run_dir)
    cfg, summary = load_run(run_dir)
    agents = summary.get("agents", [])
    if summary.get("status") != "finished":
        raise ValueError(
            f"{run_dir} has status {summary.get('status')!r}; it has no final parameters"
        )
    if not 0 <= index < len(agents):
        raise ValueError(f"--agent {index} is out of range: {run_dir} has {len(agents)} agents")
    if index in summary.get("diverged", []):
        raise ValueError(f"agent {index} of {run_dir} diverged (non-finite losses); pick another")
    params = checkpoint.load_tree(run_dir / "params")
    actor = jax.tree_util.tree_map(lambda x: np.asarray(x)[index], params["actor"])
    return cfg, agents[index], actor
