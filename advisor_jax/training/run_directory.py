"""Reading back what ``run_training`` wrote: the config, the agents, one agent's actor; and
what a resume compares and trims."""

from __future__ import annotations

import json
from pathlib import Path

import jax
import numpy as np

from advisor_jax.agent.config import TrainConfig, train_config_from_dict
from advisor_jax.fileio import atomic_write_text
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


def reevaluate(
    run_dir: str | Path,
    eval_seed: int,
    episodes: int,
    arenas: tuple[str, ...] = (),
    evaluators: dict | None = None,
) -> dict:
    """Every agent of a finished run evaluated on the episodes of ``eval_seed``: what
    eval.json would hold had the run been given ``--eval-seed eval_seed``. Runs trained
    apart can so be compared on the same episodes after the fact (pooled seeds, or a
    paired comparison of one seed under two settings).

    Args:
      arenas: default: the arenas of the run's own evaluation (training and validation if
        it had none).
      evaluators: ``{arena: population_evaluator(...)}`` already compiled (else built here).
    """
    from advisor_jax.evaluation.evaluate import evaluate_population, population_evaluator
    from advisor_jax.training.population import eval_key

    run_dir = Path(run_dir)
    cfg, summary = load_run(run_dir)
    if summary.get("status") != "finished":
        raise ValueError(f"{run_dir} has status {summary.get('status')!r}: no final parameters")
    if episodes <= 0:
        raise ValueError(f"episodes must be a positive integer, got {episodes}")
    key = eval_key(eval_seed)
    arenas = tuple(arenas) or tuple(summary.get("evaluation") or ("training", "validation"))
    evaluators = evaluators or {
        arena: population_evaluator(
            arena, episodes, cfg.agent.actor_hidden, cfg.max_episode_steps, cfg.motion
        )
        for arena in arenas
    }
    actor = checkpoint.load_tree(run_dir / "params")["actor"]
    diverged = np.zeros(len(summary["agents"]), bool)
    diverged[summary.get("diverged", [])] = True
    return evaluate_population(evaluators, actor, key, diverged)


def differences(saved, current, path: str = "") -> list[str]:
    """Where two JSON values differ: 'config.episodes: run.json has 60, these options give
    25', one entry per differing leaf (the first 5, then a count)."""
    out: list[str] = []
    if isinstance(saved, dict) and isinstance(current, dict):
        for key in sorted(set(saved) | set(current)):
            where = f"{path}.{key}" if path else key
            if key not in saved or key not in current:
                side = "run.json lacks it" if key not in saved else "these options lack it"
                out.append(f"{where}: {side}")
            else:
                out += differences(saved[key], current[key], where)
    elif isinstance(saved, list) and isinstance(current, list) and len(saved) == len(current):
        for i, (a, b) in enumerate(zip(saved, current, strict=True)):
            out += differences(a, b, f"{path}[{i}]")
    elif saved != current:
        out.append(f"{path}: run.json has {saved!r}, these options give {current!r}")
    if not path and len(out) > 5:
        out = out[:5] + [f"and {len(out) - 5} more"]
    return out


def trim_log(log_path: Path, step: int) -> None:
    """Drops the train_log.jsonl lines of chunks after ``step`` (the checkpoint resumed
    from): they will be run, and logged, again."""
    if not log_path.exists():
        return
    kept = []
    for line in log_path.read_text().splitlines():
        try:
            if json.loads(line)["step"] > step:
                continue
        except (ValueError, KeyError, TypeError):
            continue  # a line cut off by the kill
        kept.append(line + "\n")
    atomic_write_text(log_path, "".join(kept))
