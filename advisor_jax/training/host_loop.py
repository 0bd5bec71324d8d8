"""Host loop: trains a population of agents in jitted chunks, then evaluates and saves it.

    run_training(cfg, HParams(), grid={"advisor_episodes": [100, 250]}, seeds=[0, 1], out_dir=...)

The population (grid × seeds) is one ``jit(vmap(chunk))``: one compile however many agents.
Between chunks the host shows progress, reports agents whose losses went non-finite (they
are frozen and marked, the others carry on untouched), and writes an orbax checkpoint of
the full state (parameters, targets, optimisers, buffers, RNG, counters) every few chunks so
that ``resume=True`` continues an interrupted run. At the end it writes, into ``out_dir``:

    run.json          config, agents (seed + hyperparameters), status, timings, device, jax,
                      XLA_FLAGS, each agent's final networks' sha256
    params/           orbax: final actor, critics and targets of every agent (leading axis)
    checkpoints/      orbax: the last full state, to resume from (``drop_checkpoints``: deleted
                      once the run is finished)
    metrics.npz       per agent × episode: outcome, length, return, reward per step,
                      collision speed, actor firing rate, Eq. (11) expected maximum;
                      per agent × chunk: ``log/<metric>``, the train log's series
    episodes.csv      the same, one row per (agent, episode)
    eval.json         deterministic-actor evaluation per agent and arena
    train_log.jsonl   one line per chunk: losses, Q, diagnostics (population and per agent)
    learning_curve.png, diagnostics.png
    .lock             held (flock) by the running process: pid, host, start time

Safety (docs/reliability.md): every option and size is checked before anything is written
or compiled (``limits``); the run takes ``out_dir`` exclusively (``runlock``), a new run
only an empty one, and every saved directory records the run it belongs to (``run_state``,
``manifest``); Ctrl-C, SIGTERM and SIGHUP are noted and acted on between chunks
(``interrupts``): checkpoint, status "interrupted", metrics.npz and episodes.csv of the
episodes so far. ``resume=True`` of a run killed before its first checkpoint starts it
afresh, one whose newest checkpoint is corrupt resumes from the previous good one
(``checkpoint.restore_latest``), saying so, one stopped after its training (during the final
evaluation) only finishes it, and a finished run is left as it is (but for its
checkpoints/ under ``drop_checkpoints``).
"""

from __future__ import annotations

import contextlib
import dataclasses
import datetime
import json
import os
import shutil
import signal
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
from advisor_jax.fileio import append_line, atomic_write_json
from advisor_jax.training import (
    checkpoint,
    interrupts,
    limits,
    reporting,
    run_directory,
    run_outputs,
    run_state,
    runlock,
)
from advisor_jax.training.devices import (
    Placement,
    freeze_padding,
    from_writer,
    init_population,
    is_writer,
    pad,
    place,
    put,
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
from advisor_jax.training.program import population_functions, resolve_program


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
    drop_checkpoints: bool = False,
    resume: bool = False,
    progress: bool = True,
    console: Console | None = None,
    meta: Mapping | None = None,
    program: tuple | None = None,
    chunk_program: str | None = None,
    devices: int | None = None,
    eval_seed: int | None = None,
    points: Sequence[Mapping[str, float]] | None = None,
    tracker: Any = None,
    eval_advisor: bool = False,
) -> dict:
    """Trains, evaluates and saves a population; returns the summary written to run.json.

    ``meta`` (e.g. ``{"preset": "paper"}``) is recorded in run.json as is, with the chunk's
    program where this call builds it (``"program"``, what ``--program`` reproduces).
    ``devices``: how many of ``jax.devices()`` share the agents (None: all;
    ``devices.place``). ``program`` is ``population_functions(cfg, placement)`` for that
    placement when the caller already compiled it (tests, several runs of one config); None
    builds it here, with ``chunk_program`` (``program.PROGRAMS``; None:
    ``program.choose_program``). Raises ValueError for a bad option before anything is
    written, and ``runlock.RunDirectoryBusy`` if another process is training into
    ``out_dir``. An interrupt (Ctrl-C, SIGTERM, SIGHUP) saves a checkpoint at the end of the
    current chunk and raises
    ``interrupts.Interrupted`` (a KeyboardInterrupt) whose ``detail`` says how to continue.
    ``eval_seed`` keys the evaluation episodes (None: the first seed); runs given the same
    one are evaluated on the same episodes, so their agents can be pooled and paired.
    ``points``: explicit grid points in place of the product of ``grid``'s values
    (``population.build_population``); ``grid`` then names the swept hyperparameters.
    ``tracker`` (``tracking.make_tracker``) also receives every chunk's log row.
    ``eval_advisor``: also evaluate each agent's advisor alone (under its quality knobs) on
    the same episodes: eval_advisor.json (``run_outputs.evaluate_advisor``).
    ``drop_checkpoints``: once the run is finished (this call's or an earlier one's), delete
    ``out_dir/checkpoints`` (``drop_finished_checkpoints``).
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
    limits.check_episodes(cfg.episodes)
    hp, agents = build_population(base_hp, grid, seeds, points)  # checks seeds, hyperparameters
    if eval_episodes:
        limits.check_eval_episodes(eval_episodes, len(agents))
    if len(set(eval_arenas)) != len(eval_arenas):
        raise ValueError(f"an evaluation arena is named twice: {', '.join(eval_arenas)}")
    eval_from = check_seed(seeds[0] if eval_seed is None else eval_seed, "eval_seed")
    baseline = cfg.agent.baseline
    check_baseline_hparams(baseline, cfg.episodes, hp, grid, cfg.agent.name)
    placement = place(len(agents), devices)
    if program is None:  # not compiled yet
        chunk_program = resolve_program(chunk_program, placement, cfg.agent.precision)
        program = population_functions(cfg, placement, chunk_program)
        meta = {**(meta or {}), "program": chunk_program}
    limits.check_steps(program[0].max_steps, cfg.chunk_steps)
    keys = agent_keys([a["seed"] for a in agents])
    abstract = jax.eval_shape(jax.vmap(program[0].init), keys)
    limits.check_state_fits(abstract, placement.n_devices, placement.n_padded, len(agents))
    if resume and not (out_dir / "run.json").exists():
        raise ValueError(f"nothing to resume: {out_dir / 'run.json'} does not exist")
    lock = runlock.exclusive(out_dir) if is_writer() else contextlib.nullcontext()
    announce = lambda line: console.print(line, soft_wrap=True, highlight=False)  # noqa: E731
    with lock, interrupts.stop_requests(announce) as stop:
        plan = RunPlan(
            cfg=cfg, hp=hp, agents=agents, grid=grid, out_dir=out_dir,
            eval_episodes=eval_episodes, eval_arenas=eval_arenas,
            checkpoint_every=checkpoint_every, resume=resume, progress=progress,
            console=console, meta=meta, program=program, placement=placement,
            eval_from=eval_from, tracker=tracker, eval_advisor=eval_advisor,
        )  # fmt: skip
        summary = _train_locked(plan, stop)
        if drop_checkpoints and is_writer():
            drop_finished_checkpoints(out_dir, summary, console)
        return summary


def drop_finished_checkpoints(out_dir: Path, summary: Mapping, console: Console) -> None:
    """Deletes ``out_dir/checkpoints`` of a finished run (``summary``, as run.json records
    it): they serve only to resume, which a finished run never does. The networks stay in
    params/. A run that is not finished keeps them."""
    checkpoints = out_dir / "checkpoints"
    if summary.get("status") != "finished" or not checkpoints.exists():
        return
    shutil.rmtree(checkpoints)
    console.print(f"removed {checkpoints} (--drop-checkpoints: a finished run does not resume; "
                  "its networks are in params/)")  # fmt: skip


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
    program: tuple  # ``population_functions(cfg, placement)``
    placement: Placement
    eval_from: int  # the evaluation episodes' seed
    tracker: Any = None  # ``tracking.Tracker`` or None
    eval_advisor: bool = False  # also evaluate each agent's advisor alone


def _train_locked(run: RunPlan, stop: interrupts.StopRequest) -> dict:
    """``run_training`` once its options are checked and ``out_dir`` is held.

    During training the state is padded and sharded (``devices``); everything written or
    reported is of the real agents only (``real``), gathered to the host. ``stop`` notes
    signals; they take effect between chunks (``interrupts``).

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
    run_state.check_directory(out_dir, resume)
    trainer, init_fn, chunk_fn = program
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
            checkpoint.save_step(out_dir / "checkpoints", step, host, run=identity)
        return host

    padded_hp = put(hp, placement)

    summary = {
        "advisor_jax_version": __version__,
        "created": datetime.datetime.now(datetime.UTC).isoformat(timespec="seconds"),
        "device": str(jax.devices()[0].device_kind),
        "devices": placement.n_devices,
        "processes": jax.process_count(),
        "jax": jax.__version__,
        "xla_flags": os.environ.get("XLA_FLAGS", ""),  # docs/reliability.md §2: repeatability
        "config": dataclasses.asdict(cfg),
        "agent": cfg.agent.name,
        **(meta or {}),
        "grid": {k: list(map(float, v)) for k, v in grid.items()},
        "eval_seed": eval_from,
        "agents": agents,
        "advisor": trainer.advisor.record(),  # spec, kind, sha256 of its parameters
        "status": "running",
    }
    identity = run_state.run_identity(summary["config"], agents, summary["advisor"])
    summary["identity"] = identity
    if trainer.phases is not None:  # a baseline: its phases, RL last (docs/baselines.md)
        summary["phases"] = trainer.phases.describe
    step, state, seconds_before = 0, None, 0.0
    log_path = out_dir / "train_log.jsonl"
    if resume:
        saved = run_state.resume_record(run_file, summary)  # the same run, or ValueError
        if saved["status"] == "finished":
            console.print(f"{out_dir} is a finished run: nothing to resume (its results are "
                          "as they were)")  # fmt: skip
            return saved
        if changed := run_state.compiled_by(saved, summary):
            console.print(f"warning: {'; '.join(changed)} since {out_dir} started: the rest of "
                          "it may compute with other kernels and need not repeat an unbroken "
                          "run bit for bit (docs/reliability.md §2)", markup=False)  # fmt: skip
        seconds_before = saved.get("train_seconds") or 0.0
        if checkpoint.has_checkpoints(out_dir / "checkpoints"):
            abstract = jax.eval_shape(jax.vmap(trainer.init), keys)  # the real agents
            restored = None
            if writer:  # process 0 reads the run directory; the others receive its state
                state, step = checkpoint.restore_latest(
                    out_dir / "checkpoints",
                    abstract,
                    report=lambda m: console.print(f"warning: {m}"),
                    run=summary.get("identity"),
                )
                restored = (state, np.int64(step))
            step_shape = jax.ShapeDtypeStruct((), np.int64)
            state, step = from_writer(restored, (abstract, step_shape))
            state, step = start(state), int(step)
            if writer:
                run_directory.trim_log(log_path, step, n_agents)
            console.print(f"resuming {out_dir} at environment step {step}")
        else:  # killed before its first checkpoint: nothing to lose by starting again
            if writer:
                log_path.unlink(missing_ok=True)
            console.print(f"{out_dir} has no checkpoint yet (stopped before the first one): "
                          "starting it afresh")  # fmt: skip
    done = False
    if state is None:
        state = init_population(init_fn, keys, placement, n_total)
    else:
        done = _all_done(real(state.episodes), real(state.diverged), n_total)
        if done:
            console.print(f"{out_dir} finished its training before it stopped: finishing it "
                          "(final parameters and evaluation), no more training")  # fmt: skip
    if writer:
        atomic_write_json(run_file, summary)

    reported = np.zeros(n_agents, bool)
    t_start = time.perf_counter()
    chunks = 0

    def train_seconds():
        return seconds_before + time.perf_counter() - t_start

    try:
        stop.check()
        with reporting.training_progress(console, n_agents * n_total, disable=not progress) as bar:
            while not done and step < trainer.max_steps:
                state, metrics = chunk_fn(state, padded_hp, jnp.int32(step))  # donates `state`
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
                    append_line(log_path, json.dumps(line, allow_nan=False))
                    if run.tracker is not None:
                        run.tracker.log_chunk(line)
                bar.update(int(episodes.sum()), line)
                done = _all_done(episodes, diverged, n_total)
                if not done and checkpoint_every and chunks % checkpoint_every == 0:
                    save_checkpoint(state)
                stop.check()  # the chunk, its log row and its checkpoint are complete
        seconds = train_seconds()
        save_checkpoint(state)
        stop.check()
    except KeyboardInterrupt as e:
        host = save_checkpoint(state)  # gathered by every process, as `real` requires
        if writer:
            run_outputs.write_episode_metrics(out_dir, host, hp, agents, trainer.phases)
        where = f"at environment step {step}: checkpoint saved; continue with --resume"
        _stopped(e, run_file, summary, step, train_seconds(), where, writer)
    state = real(state)
    if not writer:
        return summary
    try:
        return run_outputs.finish_run(
            out_dir, state, hp, cfg, agents, grid, dict(summary), console, trainer.phases,
            train_seconds=seconds, eval_episodes=eval_episodes, eval_arenas=eval_arenas,
            eval_key=eval_key(eval_from), check=stop.check, eval_advisor=run.eval_advisor,
        )  # fmt: skip
    except KeyboardInterrupt as e:
        where = ("after training, during the final evaluation: training is complete and "
                 "saved; --resume finishes the run without training more")  # fmt: skip
        _stopped(e, run_file, summary, step, seconds, where, writer)


def _stopped(signal_error, run_file, summary, step, seconds, where, writer):
    """Records an interrupted run in run.json and raises ``Interrupted`` saying ``where``."""
    summary.update(status="interrupted", env_steps_per_agent=step, train_seconds=round(seconds, 2))
    if writer:
        atomic_write_json(run_file, summary)
    signum = getattr(signal_error, "signum", signal.SIGINT)
    raise interrupts.Interrupted(signum, f"{where} (--out {run_file.parent})") from None


def _all_done(episodes: np.ndarray, diverged: np.ndarray, n_total: int) -> bool:
    """Whether every agent has played its episodes or is frozen (diverged)."""
    return bool(np.all((np.asarray(episodes) >= n_total) | np.asarray(diverged)))
