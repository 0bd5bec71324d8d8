"""Reading back what ``run_training`` wrote: the config, the agents, one agent's actor; and
what a resume compares and trims."""

from __future__ import annotations

import json
from pathlib import Path

import jax
import numpy as np

from advisor_jax.agent.config import TrainConfig, train_config_from_dict
from advisor_jax.fileio import atomic_write_text
from advisor_jax.training import checkpoint, reporting
from advisor_jax.training.run_state import differences, read_run_json  # noqa: F401


def load_run(run_dir: str | Path) -> tuple[TrainConfig, dict]:
    """(static config, run.json summary) of a training run directory; ValueError naming the
    file and field if run.json is not a run record (``run_state.read_run_json``)."""
    run_dir = Path(run_dir)
    path = run_dir / "run.json"
    if not path.exists():
        raise ValueError(f"{run_dir} is not a training run (no run.json)")
    summary = read_run_json(path)
    if summary.get("kind") == "brax":
        raise ValueError(
            f"{run_dir} is a {summary.get('agent')} run: brax's own networks, not advisor-jax's "
            "actor (evaluate --policy RUN:AGENT scores it; export takes advisor-jax's agents "
            "only)"
        )
    try:
        return train_config_from_dict(summary["config"]), summary
    except ValueError as e:
        raise ValueError(f"{path}: {e}") from None


def load_params(run_dir: str | Path, summary: dict) -> dict:
    """params/ of a finished run, verified: its checksums, and, for runs that record their
    identity (this version's), that they are this run's (``checkpoint.load_tree``): a
    params/ copied from another run, or one whose sha256.json was deleted, is refused."""
    run_dir = Path(run_dir)
    if summary.get("status") != "finished":
        raise ValueError(
            f"{run_dir} has status {summary.get('status')!r}; it has no final parameters"
        )
    identity = summary.get("identity")
    return checkpoint.load_tree(
        run_dir / "params", run=identity, manifest=summary.get("params_sha256")
    )


def load_actor(run_dir: str | Path, index: int) -> tuple[TrainConfig, dict, dict]:
    """(config, agent row of run.json, actor params) of agent ``index`` of a finished run."""
    run_dir = Path(run_dir)
    cfg, summary = load_run(run_dir)
    agents = summary["agents"]
    if summary["status"] != "finished":
        raise ValueError(f"{run_dir} has status {summary['status']!r}; it has no final parameters")
    if not 0 <= index < len(agents):
        raise ValueError(f"--agent {index} is out of range: {run_dir} has {len(agents)} agents")
    if index in summary.get("diverged", []):
        raise ValueError(f"agent {index} of {run_dir} diverged (non-finite losses); pick another")
    params = load_params(run_dir, summary)
    actor = jax.tree_util.tree_map(lambda x: np.asarray(x)[index], params["actor"])
    return cfg, agents[index], actor


def load_agent_policy(run_dir: str | Path, index: int):
    """``(policy_apply, params)`` of agent ``index`` of a finished run: advisor-jax's actor
    (``make_actor``), or a brax agent's policy (``agent.brax_agents.policy_apply``)."""
    run_dir = Path(run_dir)
    summary = read_run_json(run_dir / "run.json")
    if summary.get("kind") != "brax":
        from advisor_jax.agent.networks import make_actor

        cfg, _, actor = load_actor(run_dir, index)
        return make_actor(cfg.agent.actor_hidden).apply, actor
    from advisor_jax.agent.brax_agents import policy_apply, settings_from_dict

    settings = settings_from_dict(summary["agent"], summary["config"]["brax"])
    params = load_params(run_dir, summary)
    return policy_apply(settings), jax.tree_util.tree_map(lambda x: np.asarray(x)[index], params)


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
    from advisor_jax.training.limits import check_eval_episodes
    from advisor_jax.training.population import eval_key

    run_dir = Path(run_dir)
    cfg, summary = load_run(run_dir)
    if summary["status"] != "finished":
        raise ValueError(f"{run_dir} has status {summary['status']!r}: no final parameters")
    check_eval_episodes(episodes, len(summary["agents"]), "episodes")
    key = eval_key(eval_seed)
    arenas = tuple(arenas) or tuple(summary.get("evaluation") or ("training", "validation"))
    evaluators = evaluators or {
        arena: population_evaluator(
            arena, episodes, cfg.agent.actor_hidden, cfg.max_episode_steps, cfg.motion
        )
        for arena in arenas
    }
    actor = load_params(run_dir, summary)["actor"]
    diverged = np.zeros(len(summary["agents"]), bool)
    diverged[summary.get("diverged", [])] = True
    return evaluate_population(evaluators, actor, key, diverged)


def trim_log(log_path: Path, step: int, n_agents: int) -> None:
    """Keeps the train_log.jsonl lines of chunks up to ``step`` (the checkpoint resumed
    from): later ones will be run, and logged, again. A line that is not a chunk row of
    ``n_agents`` agents (cut off by a kill, or edited) is dropped too."""
    if not log_path.exists():
        return
    kept = []
    for line in log_path.read_text(errors="replace").splitlines():
        try:
            row = json.loads(line)
        except (ValueError, RecursionError):
            continue  # a line cut off by the kill
        if reporting.is_chunk_row(row, n_agents) and row["step"] <= step:
            kept.append(line + "\n")
    atomic_write_text(log_path, "".join(kept))
