"""Arena calibration on the control (issue 35, item 2): DDPG in each candidate arena setting.

The paper's DDPG reaches 72.2 % (training) / 71.3 % (validation) after 500 episodes
(Table 1). The arena must be calibrated on the agents that do not contain the method under
test, DDPG and the advisor, never on the advisor-based agents. For every candidate motion
setting (``--candidates``: ``kinematic`` is today's arena, ``mjx`` the calibrated P3DX,
others vary the open parameters) and preset (``--presets``), this trains ``--seeds`` DDPG
agents as one population (``advisor-jax train``'s own ``run_training``), evaluates them on
shared episodes, evaluates the advisor (Algorithm A1) over ``--advisor-episodes`` in the
same arena setting, and writes one compact JSON (and a table) of the success, collision
and timeout rates and collision speeds: mean and 95 % interval over seeds.

Run directories go to ``<runs>/<candidate>/<preset>``; a finished one is reused, an
interrupted one resumed, and ``<out>.json`` keeps the rows of earlier calls with the same
study settings (the advisor's too), so the study may be split over several calls, e.g.
one per candidate and preset.

    python experiments/calibrate_arena.py --date 2026-11-26   # GPU (docs/arena_calibration.md)
    python experiments/calibrate_arena.py --candidates mjx --presets quick --seeds 1 \\
        --episodes 2 --max-episode-steps 20 --eval-episodes 4 --advisor-episodes 4 \\
        --runs /tmp/cal --out /tmp/cal/result                     # CPU smoke (tests)
"""

from __future__ import annotations

import dataclasses
import json
import pathlib
import sys

import common
import jax
import tyro

import envs
from advisor_jax.agent.advisor import advisor_action, arena_advisor
from advisor_jax.agent.config import preset
from advisor_jax.evaluation.evaluate import make_evaluate, summary
from advisor_jax.fileio import atomic_write_json
from advisor_jax.training.population import seed_key
from advisor_jax.training.reporting import mean_ci95
from advisor_jax.training.run_directory import load_run

PAPER_DDPG = {"training": 0.722, "validation": 0.713}  # Table 1, 500 episodes
PAPER_ADVISOR = {"training": 0.536, "validation": 0.504}  # §6.1, 500 episodes


@dataclasses.dataclass(frozen=True)
class Args:
    candidates: tuple[str, ...] = (
        "kinematic",
        "mjx",
        "mjx:wheel_torque_max=0.5",
        "mjx:wheel_torque_max=0.8",
    )
    """Arena settings to compare (motion settings, envs.parse_motion): today's arena, the
    calibrated P3DX, and a harder (weaker motors) and an easier (stronger) variant."""
    presets: tuple[str, ...] = ("stable", "paper")
    """Presets to train DDPG with (advisor-jax train --preset)."""
    agent: str = "DDPG"
    """The control agent trained (DDPG; never an advisor-based agent)."""
    seeds: int = 16
    """DDPG seeds per candidate and preset (one vmapped population)."""
    episodes: int = 500
    """Training episodes per agent (the paper's Table 1: 500)."""
    max_episode_steps: int = 0
    """h_max override (0: the arena's; small values only for smoke tests)."""
    precision: str = "bf16"
    """Learner precision, fp32 or bf16 (bf16 learns DDPG the same: results/precision_study.md)."""
    eval_episodes: int = 200
    """Evaluation episodes per agent and arena (the same for every agent and candidate)."""
    advisor_episodes: int = 500
    """Advisor evaluation episodes per arena and candidate (the paper: 500)."""
    arenas: tuple[str, ...] = ("training", "validation")
    """Evaluation arenas."""
    eval_seed: int = 1000
    """Seed of the evaluation episodes (shared by every run and the advisor)."""
    runs: str = "runs/calibrate_arena"
    """Root of the run directories (<runs>/<candidate>/<preset>)."""
    out: str = "results/arena_calibration"
    """Output path without extension (.json and .md)."""
    date: str = ""
    """Date to record (default: today)."""


def _rates(per_agent: dict) -> dict:
    """Mean and 95 % half-width over agents of each rate of an eval.json arena entry."""
    out = {}
    for name in ("success", "collision", "timeout", "collision_speed"):
        mean, half = mean_ci95(per_agent[name])
        out[name] = {"mean": mean, "ci95": half}
    return out


def train_ddpg(args: Args, candidate: str, preset_name: str) -> dict:
    """One DDPG population in one arena setting: trained (or reused), its eval rates."""
    cfg, hp = preset(preset_name, args.agent, precision=args.precision)
    cfg = dataclasses.replace(
        cfg, motion=candidate, episodes=args.episodes, max_episode_steps=args.max_episode_steps
    )
    run_dir = pathlib.Path(args.runs) / candidate.replace(":", "_") / preset_name
    seeds = list(range(args.seeds))
    status = common.train_or_resume(
        run_dir,
        cfg,
        hp,
        {},
        seeds,
        eval_episodes=args.eval_episodes,
        eval_arenas=args.arenas,
        eval_seed=args.eval_seed,
        meta={"preset": preset_name, "study": "calibrate_arena"},
    )
    _, run = load_run(run_dir)
    return {
        "candidate": candidate,
        "preset": preset_name,
        "agent": args.agent,
        "seeds": len(seeds),
        "diverged": len(run.get("diverged", [])),
        "run_dir": str(run_dir),
        "status": status,
        "train_seconds": run.get("train_seconds"),
        "arenas": {arena: _rates(run["evaluation"][arena]) for arena in args.arenas},
    }


def evaluate_advisor(args: Args, candidate: str) -> dict:
    """The advisor (Alg. A1, Table A1) in each arena of one setting, on shared episodes."""
    out = {}
    for arena in args.arenas:
        env = envs.make_env(arena, motion=candidate, max_episode_steps=args.max_episode_steps)
        fn = jax.jit(make_evaluate(env, lambda p, o: advisor_action(o, p), args.advisor_episodes))
        out[arena] = summary(fn(arena_advisor(env), seed_key(args.eval_seed)))
    return {"candidate": candidate, "arenas": out}


# What makes two calls one study: everything but which candidates and presets they run.
STUDY_KEYS = ("agent", "seeds", "episodes", "max_episode_steps", "precision", "eval_episodes",
              "advisor_episodes", "arenas", "eval_seed")  # fmt: skip


def earlier_rows(args: Args) -> tuple[list[dict], list[dict]]:
    """(advisor rows, DDPG rows) of ``<out>.json`` written by calls of the same study."""
    path = pathlib.Path(args.out).with_suffix(".json")
    if not path.exists():
        return [], []
    saved = json.loads(path.read_text())
    now = json.loads(json.dumps(dataclasses.asdict(args)))  # tuples as lists, as saved
    if any(saved.get("settings", {}).get(k) != now[k] for k in STUDY_KEYS):
        return [], []  # another study: this call starts the file afresh
    return saved.get("advisor", []), saved.get("ddpg", [])


def main(args: Args) -> dict:
    for candidate in args.candidates:  # a bad setting fails before anything trains
        envs.make_env("training", motion=candidate)
    where = common.provenance()
    advisor_rows, ddpg_rows = earlier_rows(args)
    result = {
        **where,
        "date": args.date or where["date"],
        "command": common.command_line("experiments/calibrate_arena.py", sys.argv[1:]),
        "settings": dataclasses.asdict(args),
        "paper": {"DDPG": PAPER_DDPG, "advisor": PAPER_ADVISOR},
        "advisor": advisor_rows,
        "ddpg": ddpg_rows,
    }
    out = pathlib.Path(args.out)
    for candidate in args.candidates:
        if not any(row["candidate"] == candidate for row in result["advisor"]):
            result["advisor"].append(evaluate_advisor(args, candidate))
            print(result["advisor"][-1], flush=True)
        for preset_name in args.presets:
            row = train_ddpg(args, candidate, preset_name)
            result["ddpg"] = [
                r
                for r in result["ddpg"]
                if (r["candidate"], r["preset"]) != (candidate, preset_name)
            ] + [row]
            print({k: v for k, v in row.items() if k != "run_dir"}, flush=True)
            write(result, out)  # after every population: nothing is lost
    write(result, out)
    return result


def _pct(cell: dict) -> str:
    mean, half = cell["mean"], cell["ci95"]
    if mean != mean:  # NaN: no value (e.g. no collision at all)
        return "–"
    return f"{100 * mean:.1f}" + ("" if half != half else f" ± {100 * half:.1f}")


def _speed(cell: dict) -> str:
    mean, half = cell["mean"], cell["ci95"]
    if mean != mean:
        return "–"
    return f"{mean:.2f}" + ("" if half != half else f" ± {half:.2f}")


def write(result: dict, out: pathlib.Path) -> None:
    atomic_write_json(out.with_suffix(".json"), result)
    arenas = result["settings"]["arenas"]
    lines = [
        "# Arena calibration on the controls: DDPG and the advisor per arena setting",
        "",
        f"- command: `{result['command']}`",
        f"- machine: {result['host']} ({result['backend']}: {result['device']}), jax "
        f"{result['jax']}, date {result['date']}",
        f"- DDPG: {result['settings']['seeds']} seeds × {result['settings']['episodes']} "
        f"episodes, {result['settings']['precision']}; evaluation "
        f"{result['settings']['eval_episodes']} episodes per agent and arena (shared); mean ± "
        "95 % CI over seeds (%; speeds m/s)",
        f"- advisor: {result['settings']['advisor_episodes']} episodes per arena; paper: "
        "DDPG 72.2 / 71.3 %, advisor 53.6 / 50.4 % (training / validation)",
        "",
    ]
    header = ["agent", "arena setting", "preset"]
    for arena in arenas:
        header += [f"{arena} success", "collision", "timeout", "collision speed"]
    rows = []
    for adv in result["advisor"]:
        row = ["advisor", f"`{adv['candidate']}`", "–"]
        for arena in arenas:
            s = adv["arenas"][arena]
            speed = s["mean_collision_speed"]
            rates = (s["success_rate"], s["collision_rate"], s["timeout_rate"])
            row += [f"{100 * x:.1f}" for x in rates]
            row.append("–" if speed is None else f"{speed:.2f}")
        rows.append(row)
    for ddpg in result["ddpg"]:
        row = [ddpg["agent"], f"`{ddpg['candidate']}`", ddpg["preset"]]
        for arena in arenas:
            r = ddpg["arenas"][arena]
            row += [_pct(r["success"]), _pct(r["collision"]), _pct(r["timeout"]),
                    _speed(r["collision_speed"])]  # fmt: skip
        rows.append(row)
    lines += common.markdown_table(tuple(header), rows)
    common.write_markdown(out.with_suffix(".md"), lines)


if __name__ == "__main__":
    main(tyro.cli(Args))
