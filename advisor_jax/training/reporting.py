"""Host-side reporting of a training run: progress, per-episode metrics, files, plots, tables.

Per-episode metrics (paper §6): outcome, length, return, reward per step (Fig. 8), collision
speed (Fig. 9, Table 3), the actor's firing rate and the expected maximum firing rate of
Eq. (11) (Fig. 10, window w = 30 as in the figure).
"""

from __future__ import annotations

import contextlib
import csv
import io
import json
import math
from collections.abc import Mapping, Sequence
from pathlib import Path

import jax
import numpy as np
from rich.console import Console
from rich.progress import BarColumn, MofNCompleteColumn, Progress, TextColumn, TimeElapsedColumn
from rich.table import Table

import envs
from advisor_jax.agent.hparams import rl_hparams
from advisor_jax.agent.selector import expected_max_firing_rate
from advisor_jax.evaluation.evaluate import success_table
from advisor_jax.fileio import atomic_write_bytes, atomic_write_npz
from advisor_jax.stats import (
    MIN_SEEDS_FOR_INTERVAL,
    format_interval,
    seeds_and_episodes_interval,
    t_interval,
)

FIRING_WINDOW = 30  # w of Eq. (11), as in Fig. 10
METRIC_NAMES = (
    "outcome",
    "length",
    "episode_return",
    "reward_per_step",
    "collision_speed",
    "firing_rate",
    "expected_max_firing_rate",
)


class _Bar:
    def __init__(self, progress: Progress | None, task):
        self.progress, self.task = progress, task

    def update(self, completed: int, line: dict) -> None:
        if self.progress is None:
            return
        info = f"step {line['step']:,}  {line['steps_per_second']:,.0f} steps/s"
        if line.get("loss/critic") is not None:
            info += f"  critic loss {line['loss/critic']:.3g}"
        self.progress.update(self.task, completed=completed, info=info)


@contextlib.contextmanager
def training_progress(console: Console, total_episodes: int, disable: bool = False):
    """A rich progress bar over the episodes of all agents."""
    if disable:
        yield _Bar(None, None)
        return
    columns = (
        TextColumn("[bold]training"),
        BarColumn(),
        MofNCompleteColumn(),
        TextColumn("episodes"),
        TimeElapsedColumn(),
        TextColumn("{task.fields[info]}"),
    )
    with Progress(*columns, console=console, transient=False) as progress:
        task = progress.add_task("train", total=total_episodes, info="compiling…")
        yield _Bar(progress, task)


def chunk_line(step: int, seconds: float, episodes: np.ndarray, metrics: Mapping) -> dict:
    """One JSON line per chunk: progress, and each metric's mean over the chunk's steps.

    ``metrics`` values are [agents, steps] (or [agents]). Each metric appears twice: under its
    name, the mean over all agents (the progress bar's figure), and under ``per_agent``, one
    mean per agent in population order, so the grid points of a sweep can be told apart. A
    mean with no finite value (no update ran yet, a diagnostic not defined for this agent
    type, a diverged agent) is ``None``, so that the line stays strict JSON.
    """
    line = {
        "step": int(step),
        "seconds": round(seconds, 3),
        "steps_per_second": step * len(episodes) / max(seconds, 1e-9),
        "episodes_mean": float(np.mean(episodes)),
        "episodes_min": int(np.min(episodes)),
    }
    per_agent = {}
    for name, value in metrics.items():
        if name.startswith("train/"):
            continue
        value = np.asarray(value, np.float64).reshape(len(episodes), -1)
        line[name] = _finite_mean(value)
        per_agent[name] = [_finite_mean(row) for row in value]
    line["per_agent"] = per_agent
    return line


def _finite_mean(x: np.ndarray) -> float | None:
    finite = x[np.isfinite(x)]
    return float(finite.mean()) if finite.size else None


def divergence_message(agent: Mapping, grid: Mapping) -> str:
    swept = ", ".join(f"{k}={agent[k]:g}" for k in grid)
    desc = f"seed {agent['seed']}" + (f", {swept}" if swept else "")
    return (
        f"[yellow]warning:[/] agent {agent['index']} ({desc}) produced a non-finite loss; "
        "it is frozen and excluded from the results, the other agents continue"
    )


def episode_metrics(state, hp, n_total: int) -> dict[str, np.ndarray]:
    """Per agent × episode metrics from the episode logs ([agents, N_total] each)."""
    log = jax.device_get(state.log)
    outcome = np.asarray(log.outcome)
    length = np.asarray(log.length)
    played = outcome > 0
    safe = np.maximum(length, 1)
    episode = np.arange(n_total)[None, :]
    hp = rl_hparams(hp)
    eps_start = np.asarray(hp.eps_start)[:, None]
    eps_decay = np.asarray(hp.eps_decay)[:, None]
    n_t = np.asarray(hp.advisor_episodes)[:, None]
    expected = np.asarray(expected_max_firing_rate(episode, eps_start, eps_decay, FIRING_WINDOW))
    expected = np.where(episode > n_t, 1.0, np.clip(expected, 0.0, 1.0))
    return {
        "outcome": outcome,
        "length": length,
        "episode_return": np.where(played, log.episode_return, np.nan),
        "reward_per_step": np.where(played, log.episode_return / safe, np.nan),
        "collision_speed": np.where(outcome == envs.COLLISION, log.collision_speed, np.nan),
        "firing_rate": np.where(played, log.actor_steps / safe, np.nan),
        "expected_max_firing_rate": np.broadcast_to(expected, outcome.shape).astype(np.float32),
        "diverged": np.asarray(state.diverged),
        "env_steps": np.asarray(state.env_steps),
    }


def write_metrics(
    out_dir: Path,
    metrics: Mapping[str, np.ndarray],
    agents: Sequence,
    phase_names: Sequence[str] | None = None,
) -> None:
    """metrics.npz and episodes.csv (one row per agent and played episode). With
    ``phase_names`` (a baseline) the CSV's last column names each episode's phase."""
    atomic_write_npz(out_dir / "metrics.npz", **metrics)
    buf = io.StringIO()
    writer = csv.writer(buf)
    extra = ["phase"] if phase_names else []
    writer.writerow(["agent", "seed", "episode", "outcome", *METRIC_NAMES[1:], *extra])
    names = envs.OUTCOME_NAMES
    for a, agent in enumerate(agents):
        for e in np.flatnonzero(metrics["outcome"][a] > 0):
            row = [a, agent["seed"], e + 1, names[int(metrics["outcome"][a, e])]]
            row += [_fmt(metrics[m][a, e]) for m in METRIC_NAMES[1:]]
            if phase_names:
                row.append(phase_names[int(metrics["phase"][a, e])])
            writer.writerow(row)
    atomic_write_bytes(out_dir / "episodes.csv", buf.getvalue().encode())


def _fmt(x) -> str:
    x = float(x)
    return "" if math.isnan(x) else f"{x:.6g}"


def group_agents(agents: Sequence[Mapping], grid: Mapping) -> dict[tuple, list[int]]:
    """Agent indices grouped by grid point (seeds pooled)."""
    groups: dict[tuple, list[int]] = {}
    for agent in agents:
        groups.setdefault(tuple(agent[k] for k in grid), []).append(agent["index"])
    return groups


def group_label(key: tuple, grid: Mapping, default: str) -> str:
    return ", ".join(f"{k}={v:g}" for k, v in zip(grid, key, strict=True)) or default


def moving_average(x: np.ndarray, window: int) -> np.ndarray:
    """Trailing moving average along the last axis, NaN-aware (NaN where no data yet)."""
    valid = np.isfinite(x)
    csum = np.cumsum(np.where(valid, x, 0.0), axis=-1)
    ccount = np.cumsum(valid, axis=-1)
    pad = np.zeros(x.shape[:-1] + (1,))
    csum, ccount = np.concatenate([pad, csum], -1), np.concatenate([pad, ccount], -1)
    idx = np.arange(x.shape[-1])
    lo = np.maximum(idx + 1 - window, 0)
    total = csum[..., idx + 1] - csum[..., lo]
    count = ccount[..., idx + 1] - ccount[..., lo]
    with np.errstate(invalid="ignore", divide="ignore"):
        return np.where(count > 0, total / np.maximum(count, 1), np.nan)


def is_chunk_row(row, n_agents: int) -> bool:
    """Whether ``row`` (a parsed line of train_log.jsonl) is a chunk's row of ``n_agents``
    agents, as ``chunk_line`` writes it."""
    if not isinstance(row, dict) or type(row.get("step")) is not int:
        return False
    per_agent = row.get("per_agent", {})
    return isinstance(per_agent, dict) and all(
        isinstance(v, list)
        and len(v) == n_agents
        and all(x is None or (isinstance(x, int | float) and not isinstance(x, bool)) for x in v)
        for v in per_agent.values()
    )


def read_training_log(log_path: Path, n_agents: int) -> dict[str, np.ndarray]:
    """The per-agent series of ``train_log.jsonl``: ``{"step": [chunks], name: [agents,
    chunks]}`` with NaN where a chunk had no value (strict-JSON ``None``). ValueError naming
    the file and line if a line is not a chunk row of ``n_agents`` agents."""
    lines = []
    text = log_path.read_text(errors="replace") if log_path.exists() else ""
    for number, raw in enumerate(text.splitlines(), 1):
        try:
            row = json.loads(raw)
        except (ValueError, RecursionError):
            row = None
        if not is_chunk_row(row, n_agents):
            raise ValueError(
                f"{log_path}:{number} is not a row of this run's training log ({n_agents} "
                "agents): the file was edited or mixed with another run's"
            )
        lines.append(row)
    out = {"step": np.array([line["step"] for line in lines], np.int64)}
    names = {name for line in lines for name in line.get("per_agent", {})}
    for name in sorted(names):
        rows = [line.get("per_agent", {}).get(name, [None] * n_agents) for line in lines]
        out[name] = np.array(rows, np.float64).T.reshape(n_agents, len(lines))
    return out


def count_text(n: int, noun: str) -> str:
    """``"1 agent"``, ``"2 agents"``."""
    return f"{n} {noun}" if n == 1 else f"{n} {noun}s"


def seeds_text(n: int) -> str:
    return count_text(n, "seed")


def print_summary(console: Console, summary: Mapping, metrics, grid: Mapping) -> None:
    """Per grid point: final training success and evaluation success, the mean over seeds
    with the half-width of its Student-t 95 % interval (none below 3 seeds), said so in the
    table's caption."""
    agents = summary["agents"]
    evaluation = summary.get("evaluation") or {}
    table = Table(
        title=f"{summary['agent']}: {count_text(len(agents), 'agent')}",
        caption=f"success: mean over seeds ± half-width of the 95 % t interval (none below "
        f"{MIN_SEEDS_FOR_INTERVAL} seeds); n: seeds used / trained",
    )
    table.add_column("agents")
    table.add_column("n", justify="right")
    table.add_column("train success (last 10%)", justify="right")
    for arena in evaluation:
        table.add_column(f"eval success: {arena}", justify="right")
    n_total = metrics["outcome"].shape[1]
    tail = max(1, n_total // 10)
    groups, notes = group_agents(agents, grid), []
    for key, members in groups.items():
        ok = [m for m in members if not metrics["diverged"][m]]
        last = metrics["outcome"][ok, -tail:]
        train = [float(np.mean(row[row > 0] == envs.GOAL)) for row in last if (row > 0).any()]
        cells = [group_label(key, grid, summary["agent"]), f"{len(ok)}/{len(members)}"]
        cells.append(_pct(t_interval(train)))
        for arena in evaluation:
            cells.append(_pct(t_interval([evaluation[arena]["success"][m] for m in ok])))
        table.add_row(*cells)
        drawn_anew = [
            f"{arena} {_pct(seeds_and_episodes_interval(successes))}"
            for arena in evaluation
            if (successes := success_table(evaluation[arena], ok)) is not None
            and len(ok) >= MIN_SEEDS_FOR_INTERVAL
        ]
        if drawn_anew:
            label = "" if len(groups) == 1 else f"{cells[0]}: "
            notes.append(f"{label}{', '.join(drawn_anew)}")
    console.print(table)
    if notes:  # the table's ± holds the evaluation episodes fixed: every agent plays the same
        console.print("eval success for new seeds and new evaluation episodes alike "
                      "(stats.seeds_and_episodes_interval): " + "; ".join(notes),
                      highlight=False, markup=False)  # fmt: skip


def _pct(interval) -> str:
    """``"50.0 ± 9.1 %"``; below 3 seeds ``"50.0 % (n=2)"`` (``stats.format_interval``)."""
    text = format_interval(interval, scale=100)
    if text == "–":
        return text
    mean, sep, rest = text.partition(" (n=")
    return f"{mean} % ({sep.strip(' (')}{rest}" if sep else f"{text} %"
