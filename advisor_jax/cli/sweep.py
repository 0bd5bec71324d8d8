"""``advisor-jax sweep``: run a study file on every local GPU, resumably (docs/sweeps.md)."""

from __future__ import annotations

import dataclasses
import shutil
from pathlib import Path
from typing import Annotated

import jax
import tyro
from rich.console import Console
from rich.table import Table

from advisor_jax.cli.helptext import flowing
from advisor_jax.study import failures, plan_file, slurm, sweep, throughput
from advisor_jax.study import plan as planning
from advisor_jax.study.spec import StudyError, load_study


@flowing
@dataclasses.dataclass(frozen=True)
class SweepArgs:
    """Train every agent of a study file (or several): its pieces on every local GPU at once.

    Examples:
      advisor-jax sweep experiments/studies/quick.toml --out runs/quick --dry-run
      advisor-jax sweep experiments/paper/fig6.toml --out runs/fig6      # all local GPUs
      advisor-jax sweep experiments/paper/fig6.toml --out runs/fig6      # again: resumes
      advisor-jax sweep experiments/paper/fig6.toml --out runs/fig6 --slurm fig6.sh \
          --device-memory 80 --device-kind "NVIDIA H100 80GB HBM3"      # then: sbatch fig6.sh
      advisor-jax sweep experiments/paper/fig7.toml experiments/paper/fig11.toml \
          --out runs/paper --time-limit 50            # runs/paper/fig7/, runs/paper/fig11/
    """

    study: Annotated[
        tuple[Path, ...],
        tyro.conf.Positional,
        tyro.conf.arg(metavar="STUDY...", help_behavior_hint="(required)"),
    ]
    """The study file (TOML; docs/sweeps.md), or several: their pieces share the devices,
    the first study's first, each in DIR/<its name>."""
    out: Annotated[Path, tyro.conf.arg(metavar="DIR")]
    """Directory of the sweep: plan.json, runs/<piece>/, logs/ (of several studies: one
    such directory per study inside it). A second call skips the finished pieces and
    resumes interrupted ones from their checkpoints."""
    dry_run: bool = False
    """Print the plan (pieces, memory, estimated time) and train nothing."""
    piece: int | None = None
    """Train only piece I of the plan, in this process (what each worker and each Slurm
    array task runs)."""
    slurm: Path | None = None
    """Write a Slurm job-array script (task i trains piece i) to this file instead of
    training; submit it with sbatch."""
    sbatch: tuple[str, ...] = ()
    """Extra #SBATCH options for --slurm without their dashes, e.g. --sbatch partition=gpu
    account=me time=2:00:00 (each becomes "#SBATCH --partition=gpu", ...)."""
    devices: int | None = None
    """Devices the pieces are spread over (default: the local GPUs, one on a CPU)."""
    device_memory: float | None = None
    """Plan for devices of this many GiB instead of the local ones (e.g. --slurm from a
    machine without the cluster's GPUs)."""
    device_kind: str | None = None
    """With --device-memory: the device's name as JAX gives it, for the time estimate
    (e.g. "NVIDIA H100 80GB HBM3")."""
    max_agents: int | None = None
    """At most this many agents per piece (default: as many as fit one device)."""
    per_device: int = 1
    """Pieces trained at once on each device, each in its own process with that share of
    the device's memory (small pieces leave a GPU idle between kernels; docs/sweeps.md).
    A kept plan keeps its own --max-agents and --per-device."""
    time_limit: float | None = None
    """Minutes: start only the pieces predicted to end within this many minutes from now
    (each piece's estimate × what finished pieces took against theirs, kept in DIR/timing.json
    for later calls), longest first; the others wait for the next call (e.g. a job's
    wall-clock limit). Running pieces are not stopped."""
    no_progress: bool = False
    """Hide the progress display."""


def _plan(args: SweepArgs, study, out: Path):
    """The kept plan of ``out``, else a new one for the devices at hand (or described)."""
    kept = plan_file.load_plan(out, study)
    if kept is not None:
        return kept, True
    if args.device_memory is not None:
        device = planning.Device(args.device_kind or "gpu", int(args.device_memory * 2**30), 0)
        count = args.devices or 1
    else:
        local = planning.local_devices()
        device, count = local[0], args.devices or len(local)
    if count < 1:
        raise StudyError(f"--devices {count}: need at least one device")
    if args.per_device < 1:
        raise StudyError(f"--per-device {args.per_device}: need at least one piece per device")
    device = dataclasses.replace(device, processes=args.per_device)
    table = throughput.load_table()
    plan = planning.plan_study(study, device, count, args.max_agents, table)
    if strays := sweep.stray_runs(out, plan):
        raise StudyError(
            f"{out / 'runs'} holds {len(strays)} run(s) that are no piece of the plan made now "
            f"for {count} device(s) ({', '.join(strays[:4])}{', ...' if len(strays) > 4 else ''})"
            ": they were trained under another plan, whose plan.json is not in "
            f"{out}; copy that plan.json there (a plan is made for a number of devices), or "
            "move the runs out, so that finished pieces are not trained again"
        )
    return plan, False


def print_plan(console: Console, study, plan, out: Path, kept: bool) -> None:
    title = f"{study.name}: {len(plan.pieces)} pieces, {sum(p.agents for p in plan.pieces)} agents"
    table = Table(title=title + (f" (the plan kept in {out / 'plan.json'})" if kept else ""))
    for column in ("piece", "agent", "settings", "seeds", "agents", "est. min", "status"):
        table.add_column(column, justify="right" if column in ("agents", "est. min") else "left")
    for p in plan.pieces:
        group = study.groups[p.group]
        static = [f"{k}={v}" for k, v in group.static.items()]
        points = [" ".join(f"{k}={v:g}" for k, v in group.points[i].items()) for i in p.points]
        points = [text for text in points if text]
        settings = ", ".join(static) + ("; " + " | ".join(points) if points else "")
        seeds = f"{p.seeds[0]}-{p.seeds[-1]}" if len(p.seeds) > 1 else str(p.seeds[0])
        minutes = "–" if p.seconds is None else f"{p.seconds / 60:.1f}"
        status = sweep.run_status(sweep.run_dir(out, p)) or "not started"
        table.add_row(
            str(p.index), group.agent, settings or "–", seeds, str(p.agents), minutes, status
        )
    console.print(table)
    for line in plan.explained:
        console.print(f"  {line}", highlight=False, markup=False)
    finished = sweep.finished_pieces(out, plan)
    _warn_if_the_disk_is_short(console, study, plan, out, finished)
    makespan = plan.makespan(skip=finished)
    if makespan is None:
        console.print("  estimated time: unknown (see above)")
    else:
        hours = sum(p.seconds for p in plan.pieces if p.index not in finished) / 3600
        of = f" for the {len(plan.pieces) - len(finished)} unfinished pieces" if finished else ""
        console.print(
            f"  estimated time{of}: {hours:.2f} device-hours; {makespan / 60:.0f} min on "
            f"{plan.devices} device(s), longest pieces first",
            highlight=False,
        )


def _warn_if_the_disk_is_short(console, study, plan, out: Path, finished) -> None:
    """A warning where the unfinished pieces' runs may keep more than ``out``'s filesystem
    has free (``planning.kept_on_disk``: checkpoints/ counted at their bound)."""
    agents = [0] * len(study.groups)
    for piece in plan.pieces:
        if piece.index not in finished:
            agents[piece.group] += piece.agents
    configs = [study.config(g)[0] for g in study.groups]
    need = sum(planning.kept_on_disk(study, configs, agents))
    there = next(p for p in (out.absolute(), *out.absolute().parents) if p.exists())
    free = shutil.disk_usage(there).free
    if need > free:
        console.print(
            f"  warning: the unfinished pieces' runs may keep up to {planning.size_text(need)} "
            f"on disk, and {there} has {planning.size_text(free)} free"
            + ("" if study.drop_checkpoints else " (drop_checkpoints = true in [study] keeps "
               "only params/)"),
            style="yellow", highlight=False, markup=False,
        )  # fmt: skip


def _check(args: SweepArgs, studies: list) -> None:
    """The options against each other and the studies: one-line errors before any plan."""
    if not str(args.out).strip():
        raise StudyError("--out '' is empty: name the sweep's directory")
    names = [study.name for study in studies]
    if len(set(names)) < len(names):
        raise StudyError(f"studies {names}: each needs its own name (DIR/<name>)")
    if len(studies) > 1 and (args.piece is not None or args.slurm is not None):
        raise StudyError("--piece and --slurm take one STUDY (a task trains one piece of one)")
    if args.time_limit is not None:
        if args.time_limit <= 0:
            raise StudyError(f"--time-limit {args.time_limit:g}: give a positive number of minutes")
        if args.dry_run or args.piece is not None or args.slurm is not None:
            raise StudyError(
                "--time-limit is for local runs: it chooses which pieces to start, and "
                "--dry-run, --piece and --slurm start none"
            )


def sweep_command(args: SweepArgs) -> None:
    """Entry point of ``advisor-jax sweep``."""
    if not args.study:
        raise StudyError("name a STUDY file")
    if args.piece is None:
        # This process only plans and starts workers: it keeps JAX (the studies' checks build
        # populations) off the GPUs, where it would take the memory planned for the workers.
        jax.config.update("jax_platforms", "cpu")
    studies = [load_study(path) for path in args.study]  # every check before anything compiles
    _check(args, studies)
    outs = [args.out] if len(studies) == 1 else [args.out / study.name for study in studies]
    console = Console(stderr=True)
    if not console.is_terminal:
        console = Console(stderr=True, width=160)
    planned = [_plan(args, study, out) for study, out in zip(studies, outs, strict=True)]
    if args.slurm is not None and planned[0][0].device.processes > 1:
        raise StudyError(
            f"--per-device {planned[0][0].device.processes} is for local runs: a Slurm task "
            "trains one piece; plan this --out without --per-device"
        )
    jobs = [
        sweep.Job(study, out, plan)
        for study, out, (plan, _) in zip(studies, outs, planned, strict=True)
    ]
    kept = [was_kept for _, was_kept in planned]
    if args.dry_run:
        for job, was_kept in zip(jobs, kept, strict=True):
            print_plan(console, job.study, job.plan, job.out, was_kept)
        _print_total(console, jobs)
        return
    for job, was_kept in zip(jobs, kept, strict=True):
        job.out.mkdir(parents=True, exist_ok=True)
        if not was_kept:
            plan_file.save_plan(job.out, job.study, job.plan)
    job = jobs[0]
    if args.piece is not None:
        how = sweep.run_piece(job.study, job.out, job.plan, args.piece, not args.no_progress)
        console.print(
            f"piece {args.piece}: {how} ({sweep.run_dir(job.out, job.plan.pieces[args.piece])})"
        )
        return
    if args.slurm is not None:
        slurm.write_slurm(args.slurm, job.study, job.out, job.plan, list(args.sbatch))
        print_plan(console, job.study, job.plan, job.out, kept[0])
        console.print(f"wrote {args.slurm}: submit it with  sbatch {args.slurm}")
        return
    for job, was_kept in zip(jobs, kept, strict=True):
        print_plan(console, job.study, job.plan, job.out, was_kept)
    devices = planning.local_devices()[: args.devices or None]
    limit = None if args.time_limit is None else 60.0 * args.time_limit
    result = sweep.run_jobs(jobs, devices, not args.no_progress, console, time_limit=limit)
    _closing(console, args, jobs, result)


def _print_total(console: Console, jobs: list) -> None:
    """Several studies: the estimated device-hours of their unfinished pieces together."""
    if len(jobs) < 2:
        return
    todo = []
    for job in jobs:
        done = sweep.finished_pieces(job.out, job.plan)
        todo += [p for p in job.plan.pieces if p.index not in done]
    known = sum(p.seconds for p in todo if p.seconds is not None)
    unknown = sum(p.seconds is None for p in todo)
    text = f"all {len(jobs)} studies: {known / 3600:.2f} device-hours estimated for the rest"
    console.print(text + (f" ({unknown} pieces without an estimate)" if unknown else ""))


def _closing(console: Console, args: SweepArgs, jobs: list, result: dict) -> None:
    """What finished, what failed (an error) and what --time-limit left, per study."""

    def pieces(j: int, status: str) -> list[int]:
        return sorted(i for (jj, i), s in result.items() if jj == j and s == status)

    def listed(status: str) -> str:
        return "; ".join(
            f"{', '.join(map(str, pieces(j, status)))} of {job.out} (see {job.out / 'logs'})"
            for j, job in enumerate(jobs)
            if pieces(j, status)
        )

    problems = [
        f"{what}: {which}"
        for what, which in (
            ("pieces failed twice", listed(sweep.FAILED)),
            (
                f"pieces not started, every device having failed {failures.RETIRE_AFTER} pieces "
                "in a row",
                listed(sweep.STRANDED),
            ),
        )
        if which
    ]
    if problems:
        raise StudyError(
            "; ".join(problems) + "; the others are kept: run the same command again to retry them"
        )
    any_left = False
    for j, job in enumerate(jobs):
        left = pieces(j, sweep.LEFT)
        n = len(job.plan.pieces)
        console.print(f"{n - len(left)} of {n} pieces finished in {job.out / 'runs'}")
        if left:
            any_left = True
            console.print(
                f"pieces {', '.join(map(str, left))} of {job.out} would not end within "
                f"--time-limit {args.time_limit:g}: run the same command again to train them"
            )
    if not any_left:
        dirs = " ".join(str(job.out) for job in jobs)
        console.print(f"next: advisor-jax report {dirs} --out REPORT")
