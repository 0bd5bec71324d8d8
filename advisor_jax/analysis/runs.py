"""The one loader of finished runs: run directories → runs → points of pooled seeds.

    runs = load_runs([Path("results/table1_stable/run_data")])   # every finished run below
    points = pool(runs)                                           # one Point per setting

A **run** is a directory that ``advisor-jax train`` (or ``advisor-jax sweep``) wrote:
run.json, eval.json (its agents on the episodes of its evaluation seed), eval_advisor.json
(each agent's advisor alone on the same episodes, ``--eval-advisor``),
eval_episode<N>.json (its actors kept at episode N, ``--snapshot-episodes``),
eval_seed<S>.json (re-evaluated on seed S's episodes, ``advisor-jax reevaluate``) and
metrics.npz (per agent × episode; ``compact`` keeps it small). Unfinished runs are left out
with a note.

A **point** is an agent type at one budget (N_total, or N of a kept actor) and one setting
of every hyperparameter and static setting that changes what an agent learns; its seeds
come from any run at that setting (a seed found twice counts once, the first, with a
note). Runs that are pooled or compared must have been evaluated on the same episodes:
per training arena, one evaluation seed, one episode count, the same arenas. Where their
own evaluation seeds differ, a seed every run was also evaluated on is taken (or the one
``eval_seed`` names); otherwise ``load_runs`` refuses, naming the runs.
"""

from __future__ import annotations

import dataclasses
import json
from collections.abc import Sequence
from functools import cached_property
from pathlib import Path

import numpy as np

from advisor_jax.analysis.point_settings import preset_differences, settings_of
from advisor_jax.analysis.rundata import float32_digits, with_derived

EVAL_KEYS = ("success", "collision", "timeout", "collision_speed", "collision_speed_sd", "outcomes")
"""What a seed keeps of its run's evaluation (``outcomes``: its episodes' codes, runs from
2026-12-08; None before)."""


@dataclasses.dataclass
class Run:
    path: Path
    summary: dict  # run.json
    eval_seed: int  # the evaluation in use (own or re-evaluated)
    evaluation: dict  # {arena: {"success": [agents], ..., "episodes": n}}
    snapshots: dict  # {N: evaluation} of the actors kept at episode N (own eval seed only)
    command: str | None
    advisor_evaluation: dict = dataclasses.field(default_factory=dict)  # own eval seed only

    @property
    def agent(self) -> str:
        return self.summary["agent"]

    @property
    def config(self) -> dict:
        return self.summary["config"]

    @property
    def arena(self) -> str:
        return self.config.get("arena", "training")

    @property
    def evaluated_on(self) -> tuple:
        """What its agents were scored on: (eval seed, ((arena, episodes), ...))."""
        return (
            self.eval_seed,
            tuple((a, ev["episodes"]) for a, ev in sorted(self.evaluation.items())),
        )

    @cached_property
    def _metrics(self) -> dict | None:
        path = self.path / "metrics.npz"
        return with_derived(dict(np.load(path))) if path.is_file() else None

    def metrics(self) -> dict | None:
        """metrics.npz as {name: array} (per agent × episode; ``log/...`` per chunk)."""
        return self._metrics


@dataclasses.dataclass
class RunSet:
    runs: list[Run]
    notes: list[str]
    advisors: dict  # {arena: ``advisor-jax evaluate --policy advisor --json`` output}


def own_eval_seed(summary: dict) -> int:
    """The run's evaluation seed (runs before ``--eval-seed`` used their first seed)."""
    return int(summary.get("eval_seed", summary["agents"][0]["seed"]))


def _evaluations(path: Path, summary: dict) -> dict[int, dict]:
    """{eval seed: evaluation} the run directory holds."""
    out = {own_eval_seed(summary): summary.get("evaluation") or {}}
    for extra in path.glob("eval_seed*.json"):
        out.setdefault(int(extra.stem.removeprefix("eval_seed")), json.loads(extra.read_text()))
    return {seed: float32_digits(evaluation) for seed, evaluation in out.items()}


def _command(path: Path, summary: dict) -> str | None:
    """The command that trained the run: run.json's (sweep), an older script's record, or
    command.json beside it."""
    for key in ("table1", "afp_study"):
        if (summary.get(key) or {}).get("command"):
            return summary[key]["command"]
    if summary.get("command"):
        return summary["command"]
    extra = path / "command.json"
    return json.loads(extra.read_text()).get("command") if extra.is_file() else None


def find_runs(dirs: Sequence[Path]) -> tuple[list[tuple[Path, dict]], list[str], dict]:
    """Finished runs below ``dirs`` (in the order given, sorted within), notes on the others,
    and the advisor evaluations found directly in ``dirs``."""
    found, notes, advisors = [], [], {}
    for root in dirs:
        root = Path(root)
        if not root.is_dir():
            raise ValueError(f"{root} is not a directory of runs")
        for run_file in sorted(root.rglob("run.json")):
            if "checkpoints" in run_file.parts:
                continue
            summary = json.loads(run_file.read_text())
            if summary.get("status") == "finished":
                found.append((run_file.parent, summary))
            elif (evaluated := evaluated_in_full(run_file.parent, summary)) is not None:
                found.append((run_file.parent, {**summary, "evaluation": evaluated}))
                notes.append(
                    f"{run_file.parent}: stopped after its final evaluation was written (every "
                    "agent played its episodes; eval.json holds every arena): read as finished"
                )
            else:
                notes.append(f"{run_file.parent}: status {summary.get('status')!r}, left out")
        for candidate in sorted(root.glob("*.json")):
            record = json.loads(candidate.read_text())
            if isinstance(record, dict) and record.get("policy") == "advisor":
                advisors[record["arena"]] = {**record, "file": str(candidate)}
    return found, notes, advisors


def evaluated_in_full(path: Path, summary: dict) -> dict | None:
    """The final evaluation of an interrupted run that got as far as writing it, else None.

    A run stopped during its final outputs (``run_outputs.finish_run``: parameters,
    metrics, ``eval.json``, figures) has trained every agent to the end if every agent's
    episode log is full; ``eval.json``, written whole once every arena is evaluated, then
    holds the evaluation a finished run.json would carry. Anything less is left out."""
    eval_file, metrics_file = path / "eval.json", path / "metrics.npz"
    if summary.get("status") != "interrupted" or not (
        eval_file.is_file() and metrics_file.is_file()
    ):
        return None
    with np.load(metrics_file) as metrics:
        outcome = metrics["outcome"]  # [agents, N_total]; 0 = not played
        complete = outcome.shape[0] == len(summary["agents"]) and bool(np.all(outcome != 0))
    evaluation = json.loads(eval_file.read_text())
    n_agents = len(summary["agents"])
    arenas_complete = (
        isinstance(evaluation, dict)
        and evaluation
        and all(
            isinstance(v, dict)
            and isinstance(v.get("success"), list)
            and len(v["success"]) == n_agents
            for v in evaluation.values()
        )
    )
    return evaluation if complete and arenas_complete else None


def load_runs(dirs: Sequence[Path], eval_seed: int | None = None) -> RunSet:
    """Every finished run below ``dirs``, each on the evaluation they all share (module
    docstring); ValueError naming the runs where there is none."""
    found, notes, advisors = find_runs(dirs)
    by_arena: dict[str, list[tuple[Path, dict, dict]]] = {}
    for path, summary in found:
        arena = summary["config"].get("arena", "training")
        by_arena.setdefault(arena, []).append((path, summary, _evaluations(path, summary)))
    runs = []
    for arena, members in by_arena.items():
        chosen = eval_seed if eval_seed is not None else _shared_seed(members, arena)
        for path, summary, evaluations in members:
            if chosen not in evaluations:
                raise ValueError(
                    f"{path} was not evaluated on eval seed {chosen}: run "
                    f"advisor-jax reevaluate {path} --eval-seed {chosen}, or leave it out"
                )
            own = chosen == own_eval_seed(summary)
            snapshots = {
                int(n): float32_digits(ev)
                for n, ev in (summary.get("evaluation_at_episode") or {}).items()
            }
            runs.append(
                Run(
                    path,
                    summary,
                    chosen,
                    evaluations[chosen],
                    snapshots if own else {},
                    _command(path, summary),
                    float32_digits(summary.get("advisor_evaluation") or {}) if own else {},
                )
            )
            if not own and summary.get("evaluation_at_episode"):
                notes.append(
                    f"{path}: its kept actors were evaluated on eval seed "
                    f"{own_eval_seed(summary)} only, left out"
                )
        on = {r.evaluated_on for r in runs if r.arena == arena}
        if len(on) > 1:
            raise ValueError(
                f"runs trained in {arena!r} were evaluated on different episodes and cannot be "
                "pooled: "
                + "; ".join(
                    f"{r.path} (eval seed {r.eval_seed}, "
                    + ", ".join(f"{n} {a}" for a, n in r.evaluated_on[1])
                    + ")"
                    for r in runs
                    if r.arena == arena and r.evaluated_on != min(on)
                )[:400]
                + f" vs {min(on)}; report them apart"
            )
    return RunSet(runs, notes, advisors)


def _shared_seed(members, arena: str) -> int:
    own = {own_eval_seed(s) for _, s, _ in members}
    if len(own) == 1:
        return own.pop()
    shared = set.intersection(*(set(e) for _, _, e in members))
    if not shared:
        names = ", ".join(f"{p} ({own_eval_seed(s)})" for p, s, _ in members)[:400]
        raise ValueError(
            f"runs trained in {arena!r} were evaluated on different episodes (eval seeds: "
            f"{names}) and no seed is common to all; report them apart or re-evaluate them "
            "(advisor-jax reevaluate)"
        )
    return min(shared)


# -- points ---------------------------------------------------------------------------------


@dataclasses.dataclass
class Seed:
    seed: int
    run: Run
    index: int  # the agent's index in its run
    budget: int
    snapshot: bool  # a kept actor of a longer run
    evaluation: dict  # {arena: {"success": x, ...}} (None: diverged)
    advisor: dict = dataclasses.field(default_factory=dict)  # its advisor alone, same keys

    def episodes(self, name: str) -> np.ndarray | None:
        """Per-episode metric ``name`` over this agent's first ``budget`` episodes."""
        metrics = self.run.metrics()
        if metrics is None or name not in metrics:
            return None
        return np.asarray(metrics[name][self.index, : self.budget], np.float64)


@dataclasses.dataclass
class Point:
    agent: str
    budget: int
    preset: str
    settings: dict
    label: dict  # differences from the preset
    seeds: dict  # {seed: Seed}

    @property
    def arena(self) -> str:
        return self.settings["arena"]

    def scores(self, arena: str, key: str = "success") -> dict:
        """{seed: value} of the evaluation in ``arena`` (None: diverged or absent)."""
        return {s: (r.evaluation.get(arena) or {}).get(key) for s, r in self.seeds.items()}

    def seeds_and_episodes(self, arena: str):
        """``stats.seeds_and_episodes_interval`` of the seeds' success on ``arena``'s
        evaluation episodes (diverged seeds left out), or None where a seed that did not
        diverge has no per-episode outcomes (runs before 2026-12-08)."""
        from advisor_jax.evaluation.evaluate import success_table
        from advisor_jax.stats import seeds_and_episodes_interval

        kept = [r.evaluation.get(arena) or {} for r in self.seeds.values()]
        kept = [ev for ev in kept if ev.get("success") is not None]
        if not kept or any(ev.get("outcomes") is None for ev in kept):
            return None
        # pooled runs share their evaluation episodes (``pool``), so one count fits every row
        rows = {"outcomes": [ev["outcomes"] for ev in kept], "episodes": len(kept[0]["outcomes"])}
        return seeds_and_episodes_interval(success_table(rows))

    def episodes(self, name: str) -> np.ndarray | None:
        """[seeds, budget] of a per-episode metric (None where a run lacks metrics.npz)."""
        rows = [r.episodes(name) for r in self.seeds.values()]
        return None if any(r is None for r in rows) else np.stack(rows)

    def text(self, skip: Sequence[str] = ()) -> str:
        """``ATD3+AfDP, policy_delay=2`` (the label's settings not in ``skip``)."""
        extra = [f"{k}={_show(v)}" for k, v in self.label.items() if k not in skip]
        return ", ".join([self.agent, *extra])

    @property
    def snapshot(self) -> bool:
        return any(r.snapshot for r in self.seeds.values())


def _show(value) -> str:
    if isinstance(value, tuple):
        return "x".join(map(str, value))
    return f"{value:g}" if isinstance(value, float) else str(value)


def pool(runset: RunSet) -> tuple[list[Point], list[str]]:
    """The points of a run set: its runs' agents at every budget (final and kept actors)."""
    points: dict[tuple, Point] = {}
    repeats: dict[tuple, list[int]] = {}  # (run, point, budget, first run) -> seeds
    for run in runset.runs:
        budgets = [(run.config["episodes"], False, run.evaluation)]
        budgets += [(n, True, ev) for n, ev in sorted(run.snapshots.items())]
        name = run.summary.get("preset", "paper")
        for row in run.summary["agents"]:
            settings = settings_of(run.summary, row)
            for budget, snapshot, evaluation in budgets:
                key = (run.agent, budget, tuple(sorted(settings.items())))
                point = points.setdefault(
                    key,
                    Point(
                        run.agent,
                        budget,
                        name,
                        settings,
                        preset_differences(name, run.agent, settings),
                        {},
                    ),
                )
                seed, i = int(row["seed"]), int(row["index"])
                if seed in point.seeds:
                    where = (run.path, point.text(), budget, point.seeds[seed].run.path)
                    repeats.setdefault(where, []).append(seed)
                    continue
                picked = {
                    a: {k: (ev[k][i] if k in ev else None) for k in EVAL_KEYS}
                    for a, ev in evaluation.items()
                }
                advised = {
                    a: {k: ev[k][i] for k in EVAL_KEYS if k in ev}
                    for a, ev in run.advisor_evaluation.items()
                }
                point.seeds[seed] = Seed(seed, run, i, budget, snapshot, picked, advised)
    for point in points.values():
        point.seeds = dict(sorted(point.seeds.items()))
    notes = [
        f"{path}: {_seed_list(seeds)} of {text} at {budget} episodes also in {first}; counted once"
        for (path, text, budget, first), seeds in repeats.items()
    ]
    return list(points.values()), notes


def _seed_list(seeds: list[int]) -> str:
    """``seed 3``, ``seeds 0-3``, ``seeds 0, 2, 5``."""
    seeds = sorted(seeds)
    if len(seeds) == 1:
        return f"seed {seeds[0]}"
    if seeds == list(range(seeds[0], seeds[-1] + 1)):
        return f"seeds {seeds[0]}-{seeds[-1]}"
    return "seeds " + ", ".join(map(str, seeds))
