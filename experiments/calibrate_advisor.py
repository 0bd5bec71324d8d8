"""Advisor calibration (paper §6.1): success of Algorithm A1 over 500 episodes per arena.

The paper measures its advisor at 53.6 % success in the training arena and 50.4 % in the
validation arena (500 episodes each) and 32 % on the physical platform (§6.3). Our arenas
were tuned (layouts, gaps, obstacle count and the open parameters ω_max and, for the
``mjx`` motion model, the wheel torque; the advisor's published constants are untouched)
until the advisor lands near those numbers (docs/arena_calibration.md). This script
measures it for one motion model (``--motion``) and writes ``<out>.md`` and ``.json``:

* one row per arena (seed ``--seed``, ``--episodes`` episodes): success, collision and
  timeout rates, mean collision speed;
* the spread over ``--extra-seeds`` for training and validation;
* the sensitivity to ω_max (``--omega``), the main open parameter of the calibration, and
  to other motion settings (``--settings``, e.g. the mjx model's wheel torque).

    python experiments/calibrate_advisor.py            # ~10 min on a 2-core CPU
    python experiments/calibrate_advisor.py --motion mjx --out results/advisor_mjx \
        --omega 3 4 --settings mjx:wheel_torque_max=0.5 mjx:wheel_torque_max=1
"""

from __future__ import annotations

import dataclasses
import json
import pathlib
import sys

import jax
import numpy as np
import tyro

import envs
from advisor_jax.agent.advisor import advisor_action, arena_advisor
from advisor_jax.bench import measure, writing
from advisor_jax.evaluation.evaluate import make_evaluate, summary
from advisor_jax.fileio import atomic_write_json


@dataclasses.dataclass(frozen=True)
class Args:
    arenas: tuple[str, ...] = ("training", "validation", "physical", "procedural")
    """Arenas of the main table."""
    episodes: int = 500
    """Episodes per evaluation (the paper: 500)."""
    seed: int = 0
    """Seed of the main table."""
    extra_seeds: tuple[int, ...] = (1, 2, 3, 4)
    """Further seeds for training and validation (spread of the success rate)."""
    motion: str = "kinematic"
    """Motion model of every row: kinematic, mjx or mjx:KEY=VALUE,... (envs.parse_motion)."""
    omega: tuple[float, ...] = (2.0, 4.0)
    """ω_max values (rad/s) besides the default to show the sensitivity to; empty: none."""
    settings: tuple[str, ...] = ()
    """Other motion settings to show the sensitivity to (training and validation)."""
    out: str = "results/advisor"
    """Output path without extension (.md and .json)."""
    date: str = ""
    """Date to record (default: today)."""


def _advisor(params, obs):
    return advisor_action(obs, params)


def run(
    arena: str, episodes: int, seeds: tuple[int, ...], motion: str = "kinematic", **overrides
) -> list[dict]:
    env = envs.make_env(arena, motion=motion, **overrides)
    evaluate_fn = jax.jit(make_evaluate(env, _advisor, episodes))
    rows = []
    for seed in seeds:
        key = jax.random.PRNGKey(seed)
        rates, seconds = measure.run_timed(
            lambda key=key: summary(evaluate_fn(arena_advisor(env), key))
        )
        row = {
            "arena": arena,
            "seed": seed,
            "motion": env.config.motion_setting,
            "omega_max": env.config.omega_max,
            **rates,
            "seconds": round(seconds, 1),
        }
        print(json.dumps(row), flush=True)
        rows.append(row)
    return rows


def main(args: Args) -> dict:
    config = envs.make_env("training", motion=args.motion).config
    where = measure.provenance()
    result = {
        **where,
        "date": args.date or where["date"],
        "command": writing.command_line("experiments/calibrate_advisor.py", sys.argv[1:]),
        "machine": f"{where['host']}, {where['cpu_count']} CPUs, {where['device']}",
        "motion": config.motion_setting,
        "omega_max_default": config.omega_max,
        "main": [],
        "seeds": [],
        "omega": [],
        "settings": [],
    }
    for arena in args.arenas:
        result["main"] += run(arena, args.episodes, (args.seed,), args.motion)
    for arena in ("training", "validation"):
        if args.extra_seeds:
            result["seeds"] += run(arena, args.episodes, args.extra_seeds, args.motion)
        for omega in args.omega:
            result["omega"] += run(arena, args.episodes, (args.seed,), args.motion, omega_max=omega)
        for setting in args.settings:
            result["settings"] += run(arena, args.episodes, (args.seed,), setting)
    write(result, pathlib.Path(args.out))
    return result


def _pct(x: float) -> str:
    return f"{100 * x:.1f} %"


def _speed(speed: float | None) -> str:
    return "n/a" if speed is None else f"{speed:.3f} m/s"


def _rates(row: dict) -> tuple[str, str, str]:
    """Success, collision and timeout rates of a row, as table cells."""
    return tuple(_pct(row[k]) for k in ("success_rate", "collision_rate", "timeout_rate"))


def write(result: dict, out: pathlib.Path) -> None:
    atomic_write_json(out.with_suffix(".json"), result)
    paper = {"training": "53.6 %", "validation": "50.4 %", "physical": "32 % (real car)"}
    lines = [
        "# Advisor calibration (paper §6.1, §6.3)",
        "",
        f"- command: `{result['command']}`",
        f"- machine: {result['machine']}; jax {result['jax']}; date {result['date']}",
        f"- advisor: Algorithm A1 with the Table A1 constants, T_o = 0.5 m (physical 0.6 m); "
        f"ω_max = {result['omega_max_default']} rad/s, V_max = 1 m/s, dt = 0.05 s",
        f"- motion model: `{result.get('motion', 'kinematic')}` (envs/motion.py; its "
        "parameters: docs/arena_calibration.md)",
        "- each episode: random collision-free start (uniform position and heading) and goal "
        "≥ 1 m away; deterministic advisor; the first episode of each parallel env counts",
        "",
        *writing.markdown_table(
            ("arena", "episodes", "success", "collision", "timeout", "mean collision speed",
             "paper"),
            [(r["arena"], r["episodes"], *_rates(r), _speed(r["mean_collision_speed"]),
              paper.get(r["arena"], "–")) for r in result["main"]],
        ),
    ]  # fmt: skip
    if result["seeds"]:
        lines += ["", "Spread over seeds (success rate, same episodes count):", ""]
        for arena in ("training", "validation"):
            rows = [r for r in result["main"] + result["seeds"] if r["arena"] == arena]
            rates = np.array([r["success_rate"] for r in rows])
            if len(rates) < 2:
                continue
            seeds = ", ".join(str(r["seed"]) for r in rows)
            lines.append(
                f"- {arena}: mean {_pct(rates.mean())}, sd {_pct(rates.std(ddof=1))}, "
                f"min {_pct(rates.min())}, max {_pct(rates.max())} (seeds {seeds})"
            )
    if result["omega"]:
        lines += [
            "",
            "Sensitivity to ω_max (the paper does not give it), seed as above:",
            "",
        ]
        default = [r for r in result["main"] if r["arena"] in ("training", "validation")]
        rows = result["omega"] + [dict(r, omega_max=result["omega_max_default"]) for r in default]
        rows.sort(key=lambda r: (r["arena"], r["omega_max"]))
        lines += writing.markdown_table(
            ("arena", "ω_max (rad/s)", "success", "collision", "timeout"),
            [(r["arena"], r["omega_max"], *_rates(r)) for r in rows],
            formats=("", "g", ""),
        )
    if result.get("settings"):
        lines += ["", "Other motion settings (the model's parameters changed), seed as above:", ""]
        rows = sorted(result["settings"], key=lambda r: (r["arena"], r["motion"]))
        lines += writing.markdown_table(
            ("arena", "motion setting", "ω_max (rad/s)", "success", "collision", "timeout",
             "mean collision speed"),
            [(r["arena"], f"`{r['motion']}`", r["omega_max"], *_rates(r),
              _speed(r["mean_collision_speed"])) for r in rows],
            formats=("", "", "g", ""),
        )  # fmt: skip
    writing.write_markdown(out.with_suffix(".md"), lines)


if __name__ == "__main__":
    main(tyro.cli(Args))
