"""A study file: agent types × static settings × a hyperparameter grid × seeds, in TOML.

    [study]
    name = "fig7"                    # default: the file's name
    preset = "stable"
    agents = ["ADDPG+AfD"]
    seeds = 16                       # seeds first_seed .. first_seed + 15
    first_seed = 0
    eval_seed = 0                    # every agent of the study on the same episodes
    eval_episodes = 100              # per evaluation arena
    # eval_arenas = ["training", "validation"], checkpoint_every = 10 (chunks), eval_advisor
    # drop_checkpoints = true          # a finished piece keeps params/, not its replay buffers

    [static]                         # settings with their own compile; a list sweeps them
    episodes = [100, 200, 300, 400, 500]
    precision = "bf16"

    [hp]                             # one value per hyperparameter, for every point
    beta = 1.0

    [grid]                           # the cartesian product of these lists
    advisor_episodes = ["0.25 * episodes", "0.5 * episodes", "0.75 * episodes", "episodes"]

    [agent."LfD".hp]                 # per agent type: its own [hp], [grid] and [static]
    demo_episodes = "0.5 * episodes"

A value written as a string is an **expression**: numbers, + − * / ( ), and the names of the
point's other values: any hyperparameter (from the grid, [hp] or the preset) and the static
settings (``episodes`` = N_total, ``policy_delay``, ...). So N_T as a share of N_total is
``"0.5 * episodes"``, and the decay b at which ε_st − bN reaches 0 at N = N_T/2 is
``"eps_start / (advisor_episodes / 2)"`` (0 is "never"). Each grid point evaluates its
expressions with its own values; the study records both the expression and the number.

Everything is checked when the file is read, before anything compiles, with one-line errors
naming the file, the table and the value: unknown names, values out of range
(``validate_hparams``), a static setting in the grid, N_T beyond N_total.
"""

from __future__ import annotations

import dataclasses
import hashlib
import itertools
import json
import math
import tomllib
from collections.abc import Mapping
from pathlib import Path

from advisor_jax.agent.baselines import check_baseline_hparams
from advisor_jax.agent.brax_agents import brax_agent_name
from advisor_jax.agent.config import HPARAM_NAMES, preset
from advisor_jax.agent.hparams import HPARAM_DEFAULTS
from advisor_jax.agent.settings import flat_items
from advisor_jax.study.expressions import evaluate, names_in
from advisor_jax.training.population import build_population
from advisor_jax.training.request import TrainArgs, build_run

STATIC = {  # name: type; each a TrainArgs option (advisor-jax train --NAME)
    "episodes": int,
    "arena": str,
    "envs_per_agent": int,
    "updates_per_step": int,
    "max_episode_steps": int,
    "motion": str,
    "precision": str,
    "batch_size": int,
    "buffer_size": int,
    "policy_delay": int,
    "chunk_steps": int,
    "snapshot_episodes": list,
    "baseline": dict,
    "advisor": str,
}
NOT_SWEPT = ("snapshot_episodes", "baseline")  # a list or table here is one value
STUDY_KEYS = {
    "name": str,
    "preset": str,
    "agents": list,
    "seeds": int,
    "first_seed": int,
    "eval_seed": int,
    "eval_episodes": int,
    "eval_arenas": list,
    "checkpoint_every": int,
    "drop_checkpoints": bool,
    "eval_advisor": bool,
    "description": str,
}
TABLES = ("study", "static", "hp", "grid", "agent")


class StudyError(ValueError):
    """A study file that cannot run, with a one-line message naming what and where."""


@dataclasses.dataclass(frozen=True)
class Group:
    """One compile: an agent type at one combination of static settings, and its points."""

    agent: str
    static: dict  # TrainArgs options of this combination
    names: tuple[str, ...]  # the swept hyperparameters
    hp: dict  # fixed hyperparameters (numbers)
    points: tuple[dict, ...]  # {name: number} per grid point
    written: tuple[dict, ...]  # {name: value as written} per grid point


@dataclasses.dataclass(frozen=True)
class Study:
    name: str
    path: Path
    preset: str
    seeds: tuple[int, ...]
    eval_seed: int
    eval_episodes: int
    eval_arenas: tuple[str, ...] | None
    checkpoint_every: int
    groups: tuple[Group, ...]
    eval_advisor: bool = False
    drop_checkpoints: bool = False

    def args(self, group: Group) -> TrainArgs:
        """``advisor-jax train``'s options for ``group``: its static settings, and as ``--hp``
        its fixed hyperparameters and its first point's (each agent's own point replaces
        these in training; the first one lets ``build_run`` check the budget as a whole)."""
        static = dict(group.static)
        hp = {**group.hp, **(group.points[0] if group.points else {})}
        if "snapshot_episodes" in static:
            static["snapshot_episodes"] = tuple(static["snapshot_episodes"])
        if "baseline" in static:
            static["baseline"] = tuple(f"{k}={v}" for k, v in static["baseline"].items())
        return TrainArgs(
            preset=self.preset,
            agent=group.agent,
            seeds=len(self.seeds),
            seed=self.seeds[0],
            eval_seed=self.eval_seed,
            eval_episodes=self.eval_episodes,
            eval_arenas=self.eval_arenas,
            checkpoint_every=self.checkpoint_every,
            drop_checkpoints=self.drop_checkpoints,
            eval_advisor=self.eval_advisor,
            hp=tuple(f"{k}={v!r}" for k, v in hp.items()),
            **static,
        )

    def config(self, group: Group):
        """(TrainConfig, base HParams with the group's fixed hyperparameters, eval arenas)."""
        cfg, base_hp, _, _, arenas = build_run(self.args(group))
        return cfg, base_hp, arenas

    @property
    def digest(self) -> str:
        """A hash of what the study trains (not of the file's text: comments do not count)."""
        record = {k: v for k, v in dataclasses.asdict(self).items() if k not in ("path", "name")}
        if not self.eval_advisor:  # as before the option existed: older sweeps keep their plan
            del record["eval_advisor"]
        text = json.dumps(record, sort_keys=True, default=str)
        return hashlib.sha256(text.encode()).hexdigest()[:16]


# -- expressions (study/expressions.py) -----------------------------------------------------


def resolve(written: Mapping[str, object], known: Mapping[str, float], where: str) -> dict:
    """Numbers for ``written`` ({name: number or expression}); expressions may read
    ``known`` and each other. An unknown name or a cycle is a StudyError naming ``where``."""
    out = {k: float(v) for k, v in written.items() if not isinstance(v, str)}
    pending = {k: v for k, v in written.items() if isinstance(v, str)}
    while pending:
        progressed = False
        for name, text in list(pending.items()):
            try:
                needs = names_in(text)
            except ValueError as e:
                raise StudyError(f"{where} {name}: {e}") from None
            unknown = sorted(needs - set(known) - set(written))
            if unknown:
                raise StudyError(
                    f"{where} {name} = {text!r}: unknown name {unknown[0]!r} (an expression "
                    "reads hyperparameters and static settings, e.g. episodes)"
                )
            if needs <= set(known) | set(out):
                try:
                    out[name] = evaluate(text, {**known, **out})
                except ValueError as e:
                    raise StudyError(f"{where} {name}: {e}") from None
                del pending[name]
                progressed = True
        if not progressed:
            raise StudyError(f"{where}: expressions read each other in a cycle: {sorted(pending)}")
    return out


# -- reading a study file -------------------------------------------------------------------


def load_study(path: str | Path) -> Study:
    """Reads and checks a study file; every error is a one-line StudyError."""
    path = Path(path)
    try:
        raw = tomllib.loads(path.read_text())
    except OSError as e:
        raise StudyError(f"cannot read study {path}: {e.strerror or e}") from None
    except tomllib.TOMLDecodeError as e:
        raise StudyError(f"{path}: not valid TOML: {e}") from None
    try:
        return _study(path, raw)
    except StudyError as e:
        raise StudyError(f"{path}: {e}") from None


def _study(path: Path, raw: dict) -> Study:
    for table in raw:
        if table not in TABLES:
            raise StudyError(f"unknown table [{table}]; a study has {', '.join(TABLES)}")
    head = dict(raw.get("study", {}))
    for key, value in head.items():
        if key not in STUDY_KEYS:
            raise StudyError(f"[study] {key}: unknown; choose from {', '.join(STUDY_KEYS)}")
        _check_type(f"[study] {key}", value, STUDY_KEYS[key])
    for key in ("preset", "agents", "seeds"):
        if key not in head:
            raise StudyError(f"[study] needs {key}")
    if head["seeds"] < 1:
        raise StudyError(f"[study] seeds = {head['seeds']}: need at least one seed")
    agents = list(head["agents"])
    if not agents or len(set(agents)) != len(agents):
        raise StudyError("[study] agents: name each agent type once")
    per_agent = raw.get("agent", {})
    for name in per_agent:
        if name not in agents:
            raise StudyError(f"[agent.{name!r}]: not one of [study] agents {agents}")
    first = head.get("first_seed", 0)
    study = Study(
        name=head.get("name", path.stem),
        path=path,
        preset=head["preset"],
        seeds=tuple(range(first, first + head["seeds"])),
        eval_seed=head.get("eval_seed", first),
        eval_episodes=head.get("eval_episodes", 100),
        eval_arenas=tuple(head["eval_arenas"]) if "eval_arenas" in head else None,
        checkpoint_every=head.get("checkpoint_every", 10),
        groups=(),
        eval_advisor=head.get("eval_advisor", False),
        drop_checkpoints=head.get("drop_checkpoints", False),
    )
    groups = []
    for agent in agents:
        own = per_agent.get(agent, {})
        for table in own:
            if table not in ("static", "hp", "grid"):
                raise StudyError(f"[agent.{agent!r}.{table}]: an agent has static, hp and grid")
        tables = {t: {**raw.get(t, {}), **own.get(t, {})} for t in ("static", "hp", "grid")}
        groups += _groups(study, agent, **tables)
    return dataclasses.replace(study, groups=tuple(groups))


def _check_type(where: str, value, kind) -> None:
    ok = isinstance(value, kind) and not (kind is int and isinstance(value, bool))
    if not ok:
        raise StudyError(f"{where} = {value!r}: expected {kind.__name__}")


def _check_names(static: dict, hp: dict, grid: dict) -> None:
    for name in static:
        if name in HPARAM_NAMES:
            raise StudyError(f"[static] {name} is a hyperparameter: put it under [hp] or [grid]")
        if name not in STATIC:
            raise StudyError(f"[static] {name}: unknown setting; choose from {', '.join(STATIC)}")
    for table, values in (("hp", hp), ("grid", grid)):
        for name, value in values.items():
            if name in STATIC:
                raise StudyError(
                    f"[{table}] {name} is a static setting (one compile per value): put it "
                    "under [static]"
                )
            if name not in HPARAM_NAMES:
                raise StudyError(
                    f"[{table}] {name}: unknown hyperparameter; choose from "
                    f"{', '.join(HPARAM_NAMES)}"
                )
            if table == "grid" and (not isinstance(value, list) or not value):
                raise StudyError(f"[grid] {name} = {value!r}: give a non-empty list of values")
            for v in value if table == "grid" else [value]:
                if isinstance(v, bool) or not isinstance(v, int | float | str):
                    raise StudyError(f"[{table}] {name}: {v!r} is not a number or expression")
    both = sorted(set(hp) & set(grid))
    if both:
        raise StudyError(f"{both[0]} is in both [hp] and [grid]; give it once")


def _groups(study: Study, agent: str, static: dict, hp: dict, grid: dict) -> list[Group]:
    """The agent type's groups: one per combination of its static settings."""
    _check_names(static, hp, grid)
    swept = {}
    for name, value in static.items():
        values = value if isinstance(value, list) and name not in NOT_SWEPT else [value]
        for v in values:
            _check_type(f"[static] {name}", v, STATIC[name])
        swept[name] = values
    groups = []
    for combo in itertools.product(*swept.values()):
        static_values = dict(zip(swept, combo, strict=True))
        label = f"{agent}" + "".join(f", {k}={v}" for k, v in static_values.items())
        if brax_agent_name(agent) is not None:
            raise StudyError(
                f"{label}: brax agents train one seed after another with advisor-jax train, "
                "not as a study's population (experiments/paper/brax_baselines.sh)"
            )
        try:
            cfg, base = preset(study.preset, agent)
        except ValueError as e:
            raise StudyError(f"{label}: {e}") from None
        known = {**HPARAM_DEFAULTS, **{n: float(v) for n, v in flat_items(base).items()}}
        for fields in (vars(cfg), vars(cfg.agent), static_values):
            known |= {k: float(v) for k, v in fields.items() if isinstance(v, int | float)}
        fixed = resolve(hp, {k: v for k, v in known.items() if k not in hp}, f"{label}: [hp]")
        known |= fixed
        written = [dict(zip(grid, c, strict=True)) for c in itertools.product(*grid.values())]
        points = [
            resolve(p, {k: v for k, v in known.items() if k not in grid}, f"{label}: [grid]")
            for p in written
        ]
        group = Group(agent, static_values, tuple(grid), fixed, tuple(points), tuple(written))
        try:
            cfg, base, _ = study.config(group)
        except ValueError as e:
            raise StudyError(f"{label}: {e}") from None
        _check_points(study, group, cfg, base, label)
        groups.append(group)
    return groups


def _check_points(study: Study, group: Group, cfg, base, label: str) -> None:
    """Ranges, N_T against N_total and the baselines' episode counts, per point."""
    names = group.names
    for point in group.points if cfg.agent.advisor_data else ():
        n_t = point.get("advisor_episodes", base.advisor_episodes)
        if math.isfinite(n_t) and n_t > cfg.episodes:
            where = _point_text(point) or "the preset's value: set advisor_episodes under [hp]"
            raise StudyError(
                f"{label}: advisor_episodes = {n_t:g} (N_T) is beyond episodes = "
                f"{cfg.episodes} (N_total) at {where}"
            )
    grid = {n: sorted({p[n] for p in group.points}) for n in names}
    for point in group.points or ({},):
        try:
            hp, _ = build_population(
                base, grid if point else {}, study.seeds[:1], [point] if point else None
            )
            check_baseline_hparams(
                cfg.agent.baseline, cfg.episodes, hp, {**grid, **group.hp}, group.agent
            )
        except ValueError as e:
            where = _point_text(point)
            raise StudyError(f"{label}{f' at {where}' if where else ''}: {e}") from None


def _point_text(point: Mapping[str, float]) -> str:
    return ", ".join(f"{k}={v:g}" for k, v in point.items())
