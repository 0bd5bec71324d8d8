"""``advisor-jax train --agent brax-SAC|brax-PPO``: brax's trainers into a run directory.

    run_brax_training(request)        # request: ``request.build_brax_run(TrainArgs)``

brax trains one agent per call (a Python loop around ``jax.pmap``, with host callbacks),
so the seeds run one after another, each under the paper's episode budget
(``trainer.train_seed``). Each finished seed is saved at once (``agents/<i>/``), so an
interrupted run resumes at the first unfinished seed (``--resume``). At the end the run
directory holds what ``advisor-jax train`` writes for its own agents, so ``advisor-jax
report`` pools the rows with the others:

    run.json          config (arena, episodes, the brax settings), agents, status, timings,
                      each agent's env steps and completed episodes, the evaluation
    params/           each agent's policy on a leading axis (``brax_agents.stored_params``)
    metrics.npz, episodes.csv    per agent × episode (firing rates NaN: no advisor)
    eval.json         our evaluator, on the evaluation episodes of ``eval_seed``
    train_log.jsonl   one line per brax epoch: agent, seed, env step, episodes, brax metrics
    learning_curve.png
"""

from __future__ import annotations

import atexit
import contextlib
import dataclasses
import datetime
import functools
import json
import shutil
import tempfile
from pathlib import Path

import jax
import numpy as np
from rich.console import Console

import envs
from advisor_jax import __version__
from advisor_jax.agent.brax_agents import policy_apply
from advisor_jax.evaluation.evaluate import evaluate_population, policy_population_evaluator
from advisor_jax.fileio import append_line, atomic_write_json
from advisor_jax.training import checkpoint, interrupts, plots, reporting, run_state, runlock
from advisor_jax.training.brax_baselines.episodes import Budget
from advisor_jax.training.brax_baselines.request import BraxRequest
from advisor_jax.training.brax_baselines.trainer import train_seed
from advisor_jax.training.population import eval_key

BUDGET_NOTE = (
    "at most N_total episodes: brax stops once N_total episodes are complete; the policy is "
    "the one after the last epoch that ended within them (docs/baselines.md)"
)


def run_brax_training(req: BraxRequest, console: Console | None = None, progress: bool = True,
                      tracker=None) -> dict:  # fmt: skip
    """Trains every seed, evaluates and writes the run directory; returns run.json's dict.
    A signal stops it between two brax epochs (``interrupts.Interrupted``); the finished
    seeds stay saved for ``--resume``."""
    console = console or Console(stderr=True)
    agents = [{"index": i, "seed": int(s)} for i, s in enumerate(req.seeds)]
    config = {
        "arena": req.arena,
        "episodes": req.episodes,
        "max_episode_steps": req.max_episode_steps,
        "motion": req.motion,
        "brax": dataclasses.asdict(req.settings),
    }
    summary = {
        "advisor_jax_version": __version__,
        "created": datetime.datetime.now(datetime.UTC).isoformat(timespec="seconds"),
        "device": str(jax.devices()[0].device_kind),
        "devices": 1,
        "config": config,
        "agent": req.agent,
        "kind": "brax",
        "preset": req.preset,
        "grid": {},
        "eval_seed": req.eval_seed,
        "agents": agents,
        "status": "running",
        "budget": BUDGET_NOTE,
        "identity": run_state.run_identity(config, agents),
    }
    run_file = req.out / "run.json"
    if req.resume and not run_file.exists():
        raise ValueError(f"nothing to resume: {run_file} does not exist")
    announce = lambda line: console.print(line, soft_wrap=True, highlight=False)  # noqa: E731
    with runlock.exclusive(req.out), interrupts.stop_requests(announce) as stop:
        run_state.check_directory(req.out, req.resume)
        if req.resume:
            saved = run_state.resume_record(run_file, summary)
            if saved["status"] == "finished":
                console.print(f"{req.out} is a finished run: nothing to resume")
                return saved
        atomic_write_json(run_file, summary)
        try:
            results = _train_seeds(req, summary, console, progress, tracker, stop)
        except KeyboardInterrupt as e:
            done = sum((req.out / "agents" / f"{i}.json").exists() for i in range(len(agents)))
            summary["status"] = "interrupted"
            atomic_write_json(run_file, summary)
            signum = getattr(e, "signum", 2)
            raise interrupts.Interrupted(
                signum, f"during agent {done} of {len(agents)}: "
                f"{reporting.count_text(done, 'finished agent')} saved; continue with "
                f"--resume (--out {req.out})"
            ) from None  # fmt: skip
        return _finish(req, summary, results, console)


@contextlib.contextmanager
def compile_cache():
    """jax's persistent compilation cache for the block, in a folder of this process
    (removed when it exits), unless one is configured already: brax builds new jitted
    functions in every call, so each seed would compile the same programs again
    (results/brax_baselines_cpu.md). Effective only if nothing was compiled before in this
    process (jax reads the setting once), as in ``advisor-jax train``; jax may go on using
    the folder after the block, hence its lifetime."""
    if jax.config.jax_compilation_cache_dir:
        yield
        return
    names = ("jax_compilation_cache_dir", "jax_persistent_cache_min_compile_time_secs")
    before = [getattr(jax.config, n) for n in names]
    jax.config.update(names[0], str(_process_cache_folder()))
    jax.config.update(names[1], 0.5)
    try:
        yield
    finally:
        for name, value in zip(names, before, strict=True):
            jax.config.update(name, value)


@functools.cache
def _process_cache_folder() -> Path:
    folder = Path(tempfile.mkdtemp(prefix="advisor-jax-xla-"))
    atexit.register(shutil.rmtree, folder, ignore_errors=True)
    return folder


def _train_seeds(req, summary, console, progress, tracker, stop) -> list[dict]:
    """Every agent's result ({"params", "episodes", "record"}), trained or, when resuming,
    read back from ``agents/``."""
    with compile_cache():
        return _train_each(req, summary, console, progress, tracker, stop)


def _train_each(req, summary, console, progress, tracker, stop) -> list[dict]:
    env = envs.make_brax_env(req.arena, motion=req.motion, max_episode_steps=req.max_episode_steps)
    budget = Budget(req.episodes, req.settings.num_envs, env.episode_length)
    agents = summary["agents"]
    log_path = req.out / "train_log.jsonl"
    results = []
    total = len(agents) * req.episodes
    with reporting.training_progress(console, total, disable=not progress) as bar:
        for i, agent in enumerate(agents):
            saved = _load_agent(req.out, i, summary["identity"])
            if saved is not None:
                results.append(saved)
                continue
            base = sum(r["record"]["episodes_completed"] for r in results)

            def on_epoch(row, i=i, agent=agent, base=base):
                append_line(log_path, json.dumps({"agent": i, "seed": agent["seed"], **row}))
                if tracker is not None:
                    tracker.log_agent(i, row["step"], row)
                bar.update(base + min(row["episodes"], req.episodes),
                           {"step": row["step"], "steps_per_second": row["step"] /
                            max(row["seconds"], 1e-9)})  # fmt: skip
                stop.check()  # between two brax epochs

            result = train_seed(req.agent, req.settings, env, agent["seed"], budget, on_epoch)
            record = {
                "env_steps": result.env_steps,
                "episodes_completed": result.episodes_completed,
                "seconds": round(result.seconds, 2),
                "epochs": len(result.progress),
            }
            _save_agent(req.out, i, result.params, result.episodes, record, summary["identity"])
            results.append({"params": result.params, "episodes": result.episodes, "record": record})
    return results


def _save_agent(out: Path, i: int, params, episodes, record, identity) -> None:
    folder = out / "agents"
    folder.mkdir(exist_ok=True)
    checkpoint.save_tree(folder / str(i), {"params": params, "episodes": episodes}, identity)
    atomic_write_json(folder / f"{i}.json", record)  # last: the agent is complete


def _load_agent(out: Path, i: int, identity) -> dict | None:
    record_file = out / "agents" / f"{i}.json"
    if not record_file.is_file():
        return None
    tree = checkpoint.load_tree(out / "agents" / str(i), run=identity)
    return {**tree, "record": json.loads(record_file.read_text())}


def _finish(req: BraxRequest, summary: dict, results: list[dict], console: Console) -> dict:
    """params/, metrics, evaluation, learning curve and the final run.json."""
    out, agents = req.out, summary["agents"]
    stack = lambda *xs: np.stack([np.asarray(x) for x in xs])  # noqa: E731
    params = jax.tree.map(stack, *[r["params"] for r in results])
    saved = checkpoint.save_tree(out / "params", params, summary["identity"])
    summary["params_sha256"] = checkpoint.manifest_sha256(saved)
    metrics = episode_metrics([r["episodes"] for r in results], results)
    reporting.write_metrics(out, metrics, agents)
    evaluation = {}
    if req.eval_episodes:
        apply = policy_apply(req.settings)
        evaluators = {
            arena: policy_population_evaluator(
                arena, req.eval_episodes, apply, req.max_episode_steps, req.motion
            )
            for arena in req.eval_arenas
        }
        key = eval_key(req.eval_seed)
        evaluation = evaluate_population(evaluators, params, key, np.zeros(len(agents), bool))
        atomic_write_json(out / "eval.json", evaluation)
    plots.plot_learning_curves(
        out / "learning_curve.png", metrics, agents, {}, name=req.agent, arena=req.arena
    )
    records = [r["record"] for r in results]
    summary.update(
        status="finished",
        train_seconds=round(sum(r["seconds"] for r in records), 2),
        seconds_per_agent=[r["seconds"] for r in records],
        env_steps_per_agent=[int(r["env_steps"]) for r in records],
        episodes_completed=[int(r["episodes_completed"]) for r in records],
        diverged=[],
        evaluation=evaluation,
    )
    atomic_write_json(out / "run.json", summary)
    shutil.rmtree(out / "agents", ignore_errors=True)  # in params/ and metrics.npz now
    reporting.print_summary(console, summary, metrics, {})
    return summary


def episode_metrics(episodes: list[dict], results: list[dict]) -> dict[str, np.ndarray]:
    """metrics.npz's arrays [agents, N_total] from each agent's episode arrays."""
    get = lambda name: np.stack([np.asarray(e[name]) for e in episodes])  # noqa: E731
    outcome, length = get("outcome").astype(np.int32), get("length").astype(np.int32)
    played = outcome > 0
    episode_return = np.where(played, get("episode_return"), np.nan)
    nan = np.full(outcome.shape, np.nan, np.float32)
    return {
        "outcome": outcome,
        "length": length,
        "episode_return": episode_return,
        "reward_per_step": np.where(played, episode_return / np.maximum(length, 1), np.nan),
        "collision_speed": np.where(outcome == envs.COLLISION, get("collision_speed"), np.nan),
        "firing_rate": nan,  # no advisor
        "expected_max_firing_rate": nan,
        "diverged": np.zeros(len(episodes), bool),
        "env_steps": np.array([r["record"]["env_steps"] for r in results], np.int64),
    }
