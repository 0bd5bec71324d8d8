"""Running a planned study: every piece into ``DIR/runs/<piece>``, resumable, on all GPUs.

    DIR/plan.json          the plan (made by the first call; later calls keep its pieces)
    DIR/runs/<piece>/      a run directory per piece (``advisor-jax train``'s files)
    DIR/logs/<piece>.log   the output of the worker that trained it
    DIR/timing.json        what each finished piece took against its estimate (--time-limit)

``run_jobs`` starts one worker process per free device (``advisor-jax sweep STUDY --out DIR
--piece I``, pinned with ``CUDA_VISIBLE_DEVICES``; on a CPU-only machine one at a time), or
``--per-device`` K of them, each with 1/K of XLA's memory share, for the pieces of one or
several studies (a ``Job`` each: study, DIR, plan), and shows one progress display for them
all, read from each piece's ``train_log.jsonl``; ``run_local`` is one study's.
``run_piece`` is what a worker (or a Slurm array task) does: nothing for a finished piece,
``--resume`` for one started before (a checkpoint, or afresh if it was killed before its
first), a fresh run otherwise. Pieces never talk to each other; DIR collects them.

A failed piece is started once more, last and on another device where there is one; a
device on which ``RETIRE_AFTER`` pieces failed in a row takes no more (``Failures``).
"""

from __future__ import annotations

import dataclasses
import json
import os
import shlex
import statistics
import subprocess
import sys
import time
from pathlib import Path

from rich.console import Console
from rich.progress import BarColumn, MofNCompleteColumn, Progress, TextColumn, TimeElapsedColumn

from advisor_jax.fileio import atomic_write_json
from advisor_jax.study.failures import Failures, device_name
from advisor_jax.study.plan import Device, Piece, Plan
from advisor_jax.study.spec import Study, StudyError

FAILED = "failed"  # failed twice (started once more after its first failure)
LEFT = "left"  # not started: predicted to end after --time-limit
STRANDED = "stranded"  # not started: every device was taken out after failures in a row


def run_dir(out: Path, piece: Piece) -> Path:
    return out / "runs" / piece.name


def run_status(path: Path) -> str | None:
    """``status`` of the run in ``path`` ("finished", "interrupted", "running": killed or
    training now), None where none was started."""
    try:
        return json.loads((path / "run.json").read_text()).get("status", "running")
    except FileNotFoundError:
        return None
    except (OSError, json.JSONDecodeError):
        return "running"


def finished_pieces(out: Path, plan: Plan) -> frozenset[int]:
    """Indices of the plan's pieces whose run in ``out`` has finished (kept copies count)."""
    return frozenset(p.index for p in plan.pieces if run_status(run_dir(out, p)) == "finished")


def stray_runs(out: Path, plan: Plan) -> list[str]:
    """Runs in ``out/runs`` that are no piece of ``plan``: trained under another plan (one
    made for another number of devices cuts the study into other pieces)."""
    names = {p.name for p in plan.pieces}
    runs = out / "runs"
    if not runs.is_dir():
        return []
    found = (d.name for d in runs.iterdir() if (d / "run.json").is_file())
    return sorted(name for name in found if name not in names)


def piece_command(study: Study, out: Path, index: int | str, plan: Plan) -> str:
    """The command that trains piece ``index``, with the options that cut the pieces."""
    words = ["advisor-jax", "sweep", str(study.path), "--out", str(out), "--piece", str(index)]
    if plan.max_agents is not None:
        words += ["--max-agents", str(plan.max_agents)]
    if plan.device.processes > 1:
        words += ["--per-device", str(plan.device.processes)]
    return shlex.join(words)


# -- one piece ------------------------------------------------------------------------------


def run_piece(study: Study, out: Path, plan: Plan, index: int, progress: bool = True) -> str:
    """Trains piece ``index`` in this process; returns "finished" (already), "resumed" or
    "trained"."""
    if not 0 <= index < len(plan.pieces):
        raise StudyError(f"--piece {index}: the plan has pieces 0-{len(plan.pieces) - 1}")
    piece = plan.pieces[index]
    path = run_dir(out, piece)
    status = run_status(path)
    if status == "finished":
        return "finished"
    from advisor_jax.training.host_loop import run_training  # imports JAX

    group = study.groups[piece.group]
    cfg, base_hp, arenas = study.config(group)
    points = [group.points[k] for k in piece.points]
    grid = {n: sorted({p[n] for p in points}) for n in group.names}
    meta = {
        "preset": study.preset,
        "command": piece_command(study, out, index, plan),
        "study": {
            "name": study.name,
            "file": str(study.path),
            "digest": study.digest,
            "piece": index,
            "pieces": len(plan.pieces),
            "written": [group.written[k] for k in piece.points],
        },
    }
    run_training(
        cfg,
        base_hp,
        grid,
        list(piece.seeds),
        path,
        points=points if group.names else None,
        eval_episodes=study.eval_episodes,
        eval_arenas=arenas,
        eval_seed=study.eval_seed,
        checkpoint_every=study.checkpoint_every,
        drop_checkpoints=study.drop_checkpoints,
        eval_advisor=study.eval_advisor,
        resume=status is not None,
        progress=progress,
        meta=meta,
    )
    return "trained" if status is None else "resumed"


# -- every piece on the local devices -------------------------------------------------------


def _episodes_done(path: Path, agents: int) -> float:
    """Episodes the piece's agents have completed, from its train_log.jsonl's last line."""
    try:
        with open(path / "train_log.jsonl", "rb") as f:
            f.seek(max(0, os.fstat(f.fileno()).st_size - 65536))
            last = f.read().splitlines()[-1]
        return json.loads(last)["episodes_mean"] * agents
    except (OSError, IndexError, ValueError, KeyError):
        return 0.0


@dataclasses.dataclass(frozen=True)
class Job:
    """One study's sweep: its file, its DIR and its plan."""

    study: Study
    out: Path
    plan: Plan


@dataclasses.dataclass
class _Worker:
    job: int  # index into the jobs
    piece: Piece
    device: Device
    process: subprocess.Popen
    log: object
    task: int
    started: float  # time.monotonic()


def kept_ratios(out: Path, processes: int, kind: str | None = None) -> list[float]:
    """What the pieces that earlier calls finished in ``out`` with ``processes`` workers per
    device took against their estimates (``DIR/timing.json``); only those on a ``kind``
    device where there are any (two H200 pieces sharing a GPU took 1.24x, two H100 ones
    1.51x: docs/sweeps.md)."""
    records = [r for r in _timing(out) if r.get("processes") == processes and r.get("ratio")]
    same_kind = [r for r in records if r.get("device") == kind]
    return [r["ratio"] for r in same_kind or records]


def keep_ratio(out: Path, piece: Piece, device: Device, seconds: float) -> float:
    """Adds a finished piece's wall time against its estimate to ``DIR/timing.json``."""
    ratio = seconds / piece.seconds
    record = {"piece": piece.name, "device": device.kind, "processes": device.processes}
    record |= {"estimate_s": round(piece.seconds, 1), "seconds": round(seconds, 1)}
    atomic_write_json(out / "timing.json", [*_timing(out), record | {"ratio": round(ratio, 4)}])
    return ratio


def _timing(out: Path) -> list[dict]:
    try:
        records = json.loads((out / "timing.json").read_text())
    except (OSError, json.JSONDecodeError):
        return []
    return records if isinstance(records, list) else []


def first_fitting(queue: list[Piece], seconds_left: float | None, ratio: float) -> int | None:
    """Index in ``queue`` of the first piece predicted to end within ``seconds_left``: its
    estimate × ``ratio`` (what finished pieces took against their estimates). A piece
    without an estimate always fits; no limit (None): the first piece."""
    for i, piece in enumerate(queue):
        if seconds_left is None or piece.seconds is None or piece.seconds * ratio <= seconds_left:
            return i
    return None


def run_local(
    study: Study,
    out: Path,
    plan: Plan,
    devices: list[Device],
    progress: bool = True,
    console: Console | None = None,
    time_limit: float | None = None,
) -> dict[int, str]:
    """``run_jobs`` of one study: {piece: "finished" | "failed" | "left" | "stranded"}."""
    result = run_jobs([Job(study, out, plan)], devices, progress, console, time_limit)
    return {index: status for (_, index), status in result.items()}


def run_jobs(
    jobs: list[Job],
    devices: list[Device],
    progress: bool = True,
    console: Console | None = None,
    time_limit: float | None = None,
) -> dict[tuple[int, int], str]:
    """Every unfinished piece of every job, ``plan.device.processes`` workers per device at a
    time, the jobs in their order and each job's pieces longest first; returns {(job,
    piece): "finished" | "failed" | "left" | "stranded"}. With ``time_limit`` (seconds) a
    free worker takes the first piece predicted to end in time (``first_fitting``; the ratio
    is the median of what finished pieces took against their estimates, this call's and
    those in each DIR's timing.json from earlier calls with as many workers per device, or
    with none yet the workers per device, a shared GPU's slowdown at worst); pieces that
    fit nowhere are "left" for the next call; "stranded" where no device was left
    (``Failures``). Ctrl-C stops the workers (each checkpoints)."""
    console = console or Console(stderr=True)
    processes = {job.plan.device.processes for job in jobs}
    if len(processes) > 1:
        raise StudyError(
            "the kept plans of "
            + ", ".join(f"{job.out} (--per-device {job.plan.device.processes})" for job in jobs)
            + " differ in --per-device: run them in separate calls"
        )
    (processes,) = processes
    total, result, queue = _queue(jobs)
    free = [dataclasses.replace(d, processes=processes) for _ in range(processes) for d in devices]
    running: list[_Worker] = []
    deadline = None if time_limit is None else time.monotonic() + time_limit
    kind = devices[0].kind if devices else None
    ratios = [r for job in jobs for r in kept_ratios(job.out, processes, kind)]
    failures = Failures(console)
    columns = (
        TextColumn("{task.description}"),
        BarColumn(),
        MofNCompleteColumn(),
        TextColumn("episodes"),
        TimeElapsedColumn(),
    )
    with Progress(*columns, console=console, disable=not progress) as bar:
        title = " + ".join(job.study.name for job in jobs)
        overall = bar.add_task(f"[bold]{title}", total=sum(total.values()))
        try:
            while queue or running:
                while queue and free:
                    left = None if deadline is None else deadline - time.monotonic()
                    ratio = statistics.median(ratios) if ratios else float(processes)
                    live = {d.index for d in devices} - failures.retired
                    may = [k for k, (j, p) in enumerate(queue)
                           if failures.may_start((j, p.index), free, live)]  # fmt: skip
                    i = first_fitting([queue[k][1] for k in may], left, ratio)
                    if i is None:
                        break
                    (j, piece) = queue.pop(may[i])
                    device = failures.elsewhere(free, (j, piece.index))
                    free.remove(device)
                    running.append(_start(jobs, j, piece, device, bar, total))
                if not running:
                    break  # what is queued fits in no time that is left, or on no device
                time.sleep(1.0)
                for w in list(running):
                    out = jobs[w.job].out
                    done = _episodes_done(run_dir(out, w.piece), w.piece.agents)
                    bar.update(w.task, completed=done)
                    if w.process.poll() is None:
                        continue
                    w.log.close()
                    running.remove(w)
                    bar.remove_task(w.task)
                    if w.process.returncode == 0:
                        result[w.job, w.piece.index] = "finished"
                        failures.succeeded(w.device)
                        if w.piece.seconds:
                            seconds = time.monotonic() - w.started
                            ratios.append(keep_ratio(out, w.piece, w.device, seconds))
                    elif failures.failed(w, out):
                        queue.append((w.job, w.piece))  # once more, after the others
                    else:
                        result[w.job, w.piece.index] = FAILED
                    free = [d for d in free if d.index not in failures.retired]
                    if w.device.index not in failures.retired:
                        free.append(w.device)
                finished = [k for k, s in result.items() if s == "finished"]
                live = sum(
                    _episodes_done(run_dir(jobs[w.job].out, w.piece), w.piece.agents)
                    for w in running
                )
                bar.update(overall, completed=sum(total[k] for k in finished) + live)
        except KeyboardInterrupt:
            for w in running:  # a worker checkpoints on SIGINT (and on the terminal's Ctrl-C)
                w.process.send_signal(2)
            for w in running:
                w.process.wait()
            raise
    stranded = bool(queue) and len(failures.retired) == len({d.index for d in devices})
    result.update({(j, p.index): STRANDED if stranded else LEFT for j, p in queue})
    return result


def _queue(jobs: list[Job]) -> tuple[dict, dict, list]:
    """Episodes to train per (job, piece), the pieces already finished, and the queue of
    the others: the jobs in their order, each job's pieces longest first."""
    total, result, queue = {}, {}, []
    for j, job in enumerate(jobs):
        (job.out / "logs").mkdir(parents=True, exist_ok=True)
        study = job.study
        episodes = {g: study.config(group)[0].episodes for g, group in enumerate(study.groups)}
        done = finished_pieces(job.out, job.plan)
        total |= {(j, p.index): p.agents * episodes[p.group] for p in job.plan.pieces}
        result |= {(j, i): "finished" for i in done}
        todo = [p for p in job.plan.pieces if p.index not in done]
        queue += [(j, p) for p in sorted(todo, key=lambda p: -(p.seconds or p.agents))]
    return total, result, queue


def _start(jobs, j, piece, device, bar, total) -> _Worker:
    study, out = jobs[j].study, jobs[j].out
    here = str(Path(__file__).resolve().parents[2])  # the worker runs this very package
    paths = [here, *(p for p in os.environ.get("PYTHONPATH", "").split(os.pathsep) if p)]
    env = dict(os.environ, PYTHONUNBUFFERED="1", PYTHONPATH=os.pathsep.join(paths))
    if device.index is not None:
        env["CUDA_VISIBLE_DEVICES"] = str(device.index)
        if device.processes > 1:  # K workers share the GPU: each preallocates 1/K of the share
            env["XLA_PYTHON_CLIENT_MEM_FRACTION"] = f"{device.share:.4f}"
    command = [
        sys.executable,
        "-m",
        "advisor_jax.cli.main",
        "sweep",
        str(study.path),
        "--out",
        str(out),
        "--piece",
        str(piece.index),
        "--no-progress",
    ]
    log = open(out / "logs" / f"{piece.name}.log", "ab")
    name = piece.name if len(jobs) == 1 else f"{study.name}/{piece.name}"
    task = bar.add_task(f"  {name} ({device_name(device)})", total=total[j, piece.index])
    process = subprocess.Popen(command, env=env, stdout=log, stderr=subprocess.STDOUT)
    return _Worker(j, piece, device, process, log, task, time.monotonic())
