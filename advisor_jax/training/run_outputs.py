"""What a finished run writes (``host_loop.run_training``'s last part), and the episode
metrics an interrupted run writes too: params/, metrics.npz, episodes.csv, eval.json (and
eval_episode<N>.json per ``TrainConfig.snapshot_episodes``), learning_curve.png,
diagnostics.png and run.json's final summary."""

from __future__ import annotations

import jax
import numpy as np

import envs
from advisor_jax.agent.advisors import tree_sha256
from advisor_jax.agent.hparams import rl_hparams
from advisor_jax.evaluation.evaluate import (
    advisor_evaluator,
    evaluate_population,
    population_evaluator,
)
from advisor_jax.fileio import atomic_write_json
from advisor_jax.training import checkpoint, plots, reporting
from advisor_jax.training.advisor_source import resolve_advisor


def write_episode_metrics(out_dir, state, hp, agents, phases=None):
    """metrics.npz and episodes.csv of the episodes played so far (an interrupted run's too:
    its analysis need not wait for --resume); returns (metrics, per-chunk log series). A
    baseline's episodes carry their phase (``phases``: the program's ``PhaseReport``;
    ``phase``: index into its ``names``)."""
    n_total = np.asarray(state.log.outcome).shape[-1]
    metrics = reporting.episode_metrics(state, hp, n_total)
    phase_names = None
    if phases is not None:
        metrics["phase"] = phases.episode_phases(hp, n_total)
        phase_names = phases.names
    series = reporting.read_training_log(out_dir / "train_log.jsonl", len(agents))
    metrics |= {f"log/{name}": values for name, values in series.items()}  # per chunk
    reporting.write_metrics(out_dir, metrics, agents, phase_names)
    return metrics, series


def finish_run(out_dir, state, hp, cfg, agents, grid, summary, console, phases, *,
               train_seconds, eval_episodes, eval_arenas, eval_key,
               check=lambda: None, eval_advisor=False) -> dict:  # fmt: skip
    """Final parameters, metrics, evaluation, figures and the summary (process 0, host
    state of the real agents); returns the summary written to run.json. ``check`` is called
    between the stages (``interrupts.StopRequest.check``: a signal stops the run there);
    every stage rewrites its files whole, so a resumed run repeats them from the start."""
    n_total = cfg.episodes
    run_file = out_dir / "run.json"
    check()
    extra = {} if phases is None else phases.params(state)
    networks = final_params(state, cfg, extra)
    params = checkpoint.save_tree(out_dir / "params", networks, summary.get("identity"))
    summary["params_sha256"] = checkpoint.manifest_sha256(params)  # the files, as stored
    summary["agent_params_sha256"] = agent_params_sha256(networks, len(agents))
    metrics, series = write_episode_metrics(out_dir, state, hp, agents, phases)
    evaluation = {}
    if eval_episodes:
        evaluators = {
            arena: population_evaluator(
                arena, eval_episodes, cfg.agent.actor_hidden, cfg.max_episode_steps, cfg.motion
            )
            for arena in eval_arenas
        }
        evaluation = _evaluate(evaluators, state.learner.actor, eval_key, state.diverged, check)
        atomic_write_json(out_dir / "eval.json", evaluation)
        for k, n in enumerate(cfg.snapshot_episodes):  # the same episodes as eval.json
            snaps = state.snapshots
            at_n = _evaluate(
                evaluators,
                jax.tree.map(lambda p: p[:, k], snaps.actor),  # noqa: B023
                eval_key,
                snaps.diverged[:, k] | ~snaps.taken[:, k],
                check,
            )
            atomic_write_json(out_dir / f"eval_episode{n}.json", at_n)
            summary.setdefault("evaluation_at_episode", {})[str(n)] = at_n
        if eval_advisor:
            check()
            advice = evaluate_advisor(cfg, rl_hparams(hp), eval_arenas, eval_episodes, eval_key)
            atomic_write_json(out_dir / "eval_advisor.json", advice)
            summary["advisor_evaluation"] = advice
    check()
    plots.plot_learning_curves(
        out_dir / "learning_curve.png", metrics, agents, grid, name=cfg.agent.name,
        arena=cfg.arena, advisor_data=cfg.agent.advisor_data,
    )  # fmt: skip
    plots.plot_diagnostics(
        out_dir / "diagnostics.png", series, agents, grid, name=cfg.agent.name, arena=cfg.arena
    )

    diverged = np.asarray(state.diverged)
    summary.update(
        status="finished",
        train_seconds=round(train_seconds, 2),
        env_steps_per_agent=[int(s) for s in np.asarray(state.env_steps)],
        episodes_completed=[int(e) for e in np.minimum(np.asarray(state.episodes), n_total)],
        diverged=[int(i) for i in np.flatnonzero(diverged)],
        evaluation=evaluation,
    )
    atomic_write_json(run_file, summary)
    reporting.print_summary(console, summary, metrics, grid)
    return summary


def evaluate_advisor(cfg, hp, arenas, episodes: int, key) -> dict:
    """Each agent's advisor alone, under its quality knobs (``hp.quality``, stacked), on the
    episodes of ``key`` (those of eval.json): eval.json's layout, one entry per agent. Agents
    with the same knobs share one evaluation (the advisor's draws come from ``key`` too)."""
    knobs = jax.tree.map(np.asarray, hp.quality)
    table = np.stack(jax.tree.leaves(knobs), axis=-1)  # [agents, knobs]
    _, first, inverse = np.unique(table, axis=0, return_index=True, return_inverse=True)
    distinct = jax.tree.map(lambda x: x[first], knobs)  # one row per distinct setting
    out = {}
    for arena in arenas:
        env = envs.make_env(arena, max_episode_steps=cfg.max_episode_steps)
        advisor = resolve_advisor(cfg.advisor, env, check=False)  # checked by make_core
        evaluator = advisor_evaluator(env, advisor, episodes)
        result = evaluate_population({arena: evaluator}, distinct, key)[arena]
        out[arena] = {
            k: v if k == "episodes" else [v[int(i)] for i in inverse.reshape(-1)]
            for k, v in result.items()
        }
    return out


def _evaluate(evaluators, actor, key, diverged, check) -> dict:
    """``evaluate_population`` one arena at a time, with ``check`` before each."""
    out = {}
    for arena, evaluator in evaluators.items():
        check()
        out |= evaluate_population({arena: evaluator}, actor, key, np.asarray(diverged))
    return out


def agent_params_sha256(networks: dict, n_agents: int) -> list[str]:
    """Per agent, the sha256 of its final networks' values (``advisors.tree_sha256`` of its
    slice of ``networks``): equal in two runs exactly where that agent learned the same bits.
    ``params_sha256`` cannot say so: it hashes the stored files, whose names and metadata
    differ from one save to the next."""

    def agent(i: int) -> dict:
        return jax.tree.map(lambda leaf: leaf[i], networks)

    return [tree_sha256(agent(i)) for i in range(n_agents)]


def final_params(state, cfg, extra: dict | None = None) -> dict:
    """The trained networks of every agent (leading axis), as params/ holds them; ``extra``:
    what the program adds (``PhaseReport.params``: MCP+MF's dynamics model)."""
    learner = state.learner
    params = {
        "actor": learner.actor,
        "critic": learner.critic,
        "target_actor": learner.target_actor,
        "target_critic": learner.target_critic,
    }
    if cfg.snapshot_episodes:  # [agents, K, ...]
        params["actor_snapshots"] = state.snapshots.actor
    return {**params, **(extra or {})}
