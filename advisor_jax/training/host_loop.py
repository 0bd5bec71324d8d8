"""Host loop: trains a population of agents in jitted chunks, then evaluates and saves it.

    run_training(cfg, HParams(), grid={"advisor_episodes": [100, 250]}, seeds=[0, 1], out_dir=...)

The population (grid × seeds) is one ``jit(vmap(chunk))``: one compile however many agents.
Between chunks the host shows progress, reports agents whose losses went non-finite (they
are frozen and marked, the others carry on untouched), and writes an orbax checkpoint of
the full state (parameters, targets, optimisers, buffers, RNG, counters) every few chunks so
that ``resume=True`` continues an interrupted run. At the end it writes, into ``out_dir``:

    run.json          config, agents (seed + hyperparameters), status, timings, device
    params/           orbax: final actor, critics and targets of every agent (leading axis)
    metrics.npz       per agent × episode: outcome, length, return, reward per step,
                      collision speed, actor firing rate, Eq. (11) expected maximum;
                      per agent × chunk: ``log/<metric>``, the train log's series
    episodes.csv      the same, one row per (agent, episode)
    eval.json         deterministic-actor evaluation per agent and arena
    train_log.jsonl   one line per chunk: losses, Q, diagnostics (population and per agent)
    learning_curve.png, diagnostics.png
    .lock             held (flock) by the running process: pid, host, start time

Safety: every option is checked before anything is written or compiled; the run
takes ``out_dir`` exclusively (``runlock``); SIGTERM is handled like Ctrl-C (checkpoint,
status "interrupted", metrics.npz and episodes.csv of the episodes so far); ``resume=True``
of a run killed before its first checkpoint starts it afresh, and one whose newest
checkpoint is corrupt resumes from the previous good one (``checkpoint.restore_latest``),
saying so.
"""

from __future__ import annotations

import contextlib
import dataclasses
import datetime
import json
import os
import time
from collections.abc import Mapping, Sequence
from pathlib import Path
from typing import Any

import jax
import jax.numpy as jnp
import numpy as np
from rich.console import Console

import envs
from advisor_jax import __version__
from advisor_jax.agent.baselines import check_baseline_hparams
from advisor_jax.agent.config import HParams, TrainConfig
from advisor_jax.fileio import atomic_write_json
from advisor_jax.training import (
    checkpoint,
    reporting,
    run_directory,
    run_outputs,
    runlock,
)
from advisor_jax.training.devices import (
    Placement,
    freeze_padding,
    from_writer,
    is_writer,
    pad,
    place,
    shard,
    to_host,
    unpad,
)
from advisor_jax.training.population import (
    agent_keys,
    build_population,
    check_seed,
    eval_key,
)
from advisor_jax.training.program import population_functions


def run_training(
    cfg: TrainConfig,
    base_hp: HParams,
    grid: Mapping[str, Sequence[float]],
    seeds: Sequence[int],
    out_dir: str | Path,
    *,
    eval_episodes: int = 100,
    eval_arenas: Sequence[str] = ("training", "validation"),
    checkpoint_every: int = 10,
    resume: bool = False,
    progress: bool = True,
    console: Console | None = None,
    meta: Mapping | None = None,
    program: tuple | None = None,
    devices: int | None = None,
    eval_seed: int | None = None,
    points: Sequence[Mapping[str, float]] | None = None,
) -> dict:
    """Trains, evaluates and saves a population; returns the summary written to run.json.

    ``meta`` (e.g. ``{"preset": "paper"}``) is recorded in run.json as is. ``devices``: how
    many of ``jax.devices()`` share the agents (None: all; ``devices.place``). ``program``
    is ``population_functions(cfg, placement)`` for that placement when the caller already
    compiled it (tests, several runs of one config); None builds it here. Raises
    ValueError for a bad option before anything is written, and ``runlock.RunDirectoryBusy``
    if another process is training into ``out_dir``. An interrupt (Ctrl-C or SIGTERM) saves
    a checkpoint and re-raises KeyboardInterrupt (``runlock.Interrupted`` for SIGTERM).
    ``eval_seed`` keys the evaluation episodes (None: the first seed); runs given the same
    one are evaluated on the same episodes, so their agents can be pooled and paired.
    ``points``: explicit grid points in place of the product of ``grid``'s values
    (``population.build_population``); ``grid`` then names the swept hyperparameters.
    """
    console = console or Console(stderr=True)
    if not os.fspath(out_dir).strip():  # Path("") is ".": it would train into the cwd
        raise ValueError("the run directory (--out) must not be empty")
    out_dir = Path(out_dir)
    if eval_episodes < 0:
        raise ValueError(f"eval_episodes must be >= 0, got {eval_episodes}")
    if checkpoint_every < 0:
        raise ValueError(
            f"checkpoint_every must be >= 0 (0: only at the end), got {checkpoint_every}"
        )
    for what, names in (("arena", [cfg.arena]), ("evaluation arena", list(eval_arenas))):
        unknown = [a for a in names if a not in envs.ARENAS]
        if unknown:
            raise ValueError(
                f"unknown {what} {', '.join(map(repr, unknown))}; choose from "
                f"{', '.join(envs.ARENAS)}"
            )
    hp, agents = build_population(
        base_hp, grid, seeds, points
    )  # checks the seeds and hyperparameters
    eval_from = check_seed(seeds[0] if eval_seed is None else eval_seed, "eval_seed")
    baseline = cfg.agent.baseline
    check_baseline_hparams(baseline, cfg.episodes, hp, grid, cfg.agent.name)
    placement = place(len(agents), devices)
    if resume and not (out_dir / "run.json").exists():
        raise ValueError(f"nothing to resume: {out_dir / 'run.json'} does not exist")
    lock = runlock.exclusive(out_dir) if is_writer() else contextlib.nullcontext()
    with lock, runlock.sigterm_as_interrupt():
        return _train_locked(
            RunPlan(
                cfg=cfg, hp=hp, agents=agents, grid=grid, out_dir=out_dir,
                eval_episodes=eval_episodes, eval_arenas=eval_arenas,
                checkpoint_every=checkpoint_every, resume=resume, progress=progress,
                console=console, meta=meta, program=program, placement=placement,
                eval_from=eval_from,
            )
        )  # fmt: skip


@dataclasses.dataclass(frozen=True)
class RunPlan:
    """A ``run_training`` call with its options checked: what ``_train_locked`` runs."""

    cfg: TrainConfig
    hp: Any  # the real agents' stacked hyperparameters (``build_population``)
    agents: list[dict]  # run.json's rows, one per agent
    grid: Mapping[str, Sequence[float]]
    out_dir: Path
    eval_episodes: int
    eval_arenas: Sequence[str]
    checkpoint_every: int
    resume: bool
    progress: bool
    console: Console
    meta: Mapping | None
    program: tuple | None  # ``population_functions(cfg, placement)``, or None: build it
    placement: Placement
    eval_from: int  # the evaluation episodes' seed


def _train_locked(run: RunPlan) -> dict:
    """``run_training`` once its options are checked and ``out_dir`` is held.

    During training the state is padded and sharded (``devices``); everything written or
    reported is of the real agents only (``real``), gathered to the host.

    Long: the run in the order it happens (start or resume, the chunk loop with its
    checkpoints, an interrupt's checkpoint and partial outputs, the final outputs), so that
    each path's effect on the run directory reads in one place."""
    cfg, hp, agents, grid, out_dir = run.cfg, run.hp, run.agents, run.grid, run.out_dir
    eval_episodes, eval_arenas, checkpoint_every = (
        run.eval_episodes, run.eval_arenas, run.checkpoint_every
    )  # fmt: skip
    resume, progress, console, meta = run.resume, run.progress, run.console, run.meta
    program, placement, eval_from = run.program, run.placement, run.eval_from
    run_file = out_dir / "run.json"
    if run_file.exists() and not resume:
        raise ValueError(
            f"{out_dir} already holds a run; pass --resume to continue it or choose another --out"
        )
    trainer, init_fn, chunk_fn = program or population_functions(cfg, placement)
    keys = agent_keys([a["seed"] for a in agents])
    n_agents, n_total = len(agents), cfg.episodes
    writer = is_writer()

    def start(state):  # real agents' state -> padded, padding frozen, on the mesh
        return shard(freeze_padding(pad(state, placement), placement, n_total), placement)

    def real(tree):  # padded, sharded tree -> the real agents, numpy on the host
        # Cut on the host: a slice of the sharded array on the devices would all-gather it
        # onto every device first (the whole state, replay buffers included, at a checkpoint).
        return unpad(to_host(tree), placement)

    def save_checkpoint(state):
        host = real(state)  # every process takes part in the gather; process 0 writes
        if writer:
            checkpoint.save_step(out_dir / "checkpoints", step, host)
        return host

    padded_hp = shard(pad(hp, placement), placement)

    summary = {
        "advisor_jax_version": __version__,
        "created": datetime.datetime.now(datetime.UTC).isoformat(timespec="seconds"),
        "device": str(jax.devices()[0].device_kind),
        "devices": placement.n_devices,
        "processes": jax.process_count(),
        "config": dataclasses.asdict(cfg),
        "agent": cfg.agent.name,
        **(meta or {}),
        "grid": {k: list(map(float, v)) for k, v in grid.items()},
        "eval_seed": eval_from,
        "agents": agents,
        "status": "running",
    }
    if trainer.phases is not None:  # a baseline: its phases, RL last (docs/baselines.md)
        summary["phases"] = trainer.phases.describe
    step = 0
    log_path = out_dir / "train_log.jsonl"
    if resume:
        try:
            saved = json.loads(run_file.read_text())
        except json.JSONDecodeError as e:
            raise ValueError(f"cannot resume {out_dir}: {run_file} is corrupt ({e})") from None
        current = json.loads(json.dumps({"config": summary["config"], "agents": agents}))
        differences = run_directory.differences({k: saved.get(k) for k in current}, current)
        if differences:
            raise ValueError(
                f"cannot resume {out_dir}: its config or agents differ from these: "
                + "; ".join(differences)
            )
        summary["created"] = saved.get("created", summary["created"])
        if checkpoint.has_checkpoints(out_dir / "checkpoints"):
            abstract = jax.eval_shape(jax.vmap(trainer.init), keys)  # the real agents
            restored = None
            if writer:  # process 0 reads the run directory; the others receive its state
                state, step = checkpoint.restore_latest(
                    out_dir / "checkpoints",
                    abstract,
                    report=lambda m: console.print(f"warning: {m}"),
                )
                restored = (state, np.int64(step))
            step_shape = jax.ShapeDtypeStruct((), np.int64)
            state, step = from_writer(restored, (abstract, step_shape))
            state, step = start(state), int(step)
            if writer:
                run_directory.trim_log(log_path, step)
            console.print(f"resuming {out_dir} at environment step {step}")
        else:  # killed before its first checkpoint: nothing to lose by starting again
            state = None
            if writer:
                log_path.unlink(missing_ok=True)
            console.print(f"{out_dir} has no checkpoint yet (stopped before the first one): "
                          "starting it afresh")  # fmt: skip
    else:
        state = None
    if state is None:
        state = freeze_padding(init_fn(shard(pad(keys, placement), placement)), placement, n_total)
    if writer:
        atomic_write_json(run_file, summary)

    reported = np.zeros(n_agents, bool)
    t_start = time.perf_counter()
    chunks = 0
    try:
        with reporting.training_progress(console, n_agents * n_total, disable=not progress) as bar:
            while step < trainer.max_steps:
                with runlock.interrupts_deferred():  # the call donates `state`
                    state, metrics = chunk_fn(state, padded_hp, jnp.int32(step))
                    step += cfg.chunk_steps
                chunks += 1
                metrics = real(metrics)
                episodes = np.minimum(real(state.episodes), n_total)
                diverged = real(state.diverged)
                for i in np.flatnonzero(diverged & ~reported):
                    console.print(reporting.divergence_message(agents[i], grid))
                reported |= diverged
                line = reporting.chunk_line(step, time.perf_counter() - t_start, episodes, metrics)
                if writer:
                    with open(log_path, "a") as f:
                        f.write(json.dumps(line, allow_nan=False) + "\n")
                bar.update(int(episodes.sum()), line)
                if np.all((episodes >= n_total) | diverged):
                    break
                if checkpoint_every and chunks % checkpoint_every == 0:
                    save_checkpoint(state)
    except KeyboardInterrupt as e:
        host = save_checkpoint(state)  # gathered by every process, as `real` requires
        summary.update(status="interrupted", env_steps_per_agent=step)
        if writer:
            run_outputs.write_episode_metrics(out_dir, host, hp, agents, trainer.phases)
            atomic_write_json(run_file, summary)
        what = "SIGTERM" if isinstance(e, runlock.Interrupted) else "interrupted"
        console.print(
            f"{what} at environment step {step}; checkpoint saved, continue with --resume "
            f"(--out {out_dir})"
        )
        raise
    train_seconds = time.perf_counter() - t_start
    save_checkpoint(state)
    state = real(state)
    if not writer:
        return summary

    return run_outputs.finish_run(
        out_dir, state, hp, cfg, agents, grid, summary, console, trainer.phases,
        train_seconds=train_seconds, eval_episodes=eval_episodes, eval_arenas=eval_arenas,
        eval_key=eval_key(eval_from),
    )  # fmt: skip
