"""Paper Tables 2 and 3: agents trained in the physical arena for 100, 150 and 200 episodes
(Table 2), and the collision speeds of those trained for 200 (Table 3).

    # one run per agent type: 200 episodes, the actors of episodes 100 and 150 kept
    # (--snapshot-episodes: the actor a 100- or 150-episode run ends with), every type
    # scored on the same 100 episodes of the physical arena (the paper's 100 test episodes)
    advisor-jax train --preset physical --agent ATD3+AfDP --seeds 16 --eval-episodes 100 \\
        --snapshot-episodes 100 150 --out runs/table2/ATD3_AfDP
    # the advisor's own collision speeds (Table 3's first row)
    advisor-jax evaluate --policy advisor --arena physical --episodes 1600 --json \\
        > runs/table2/advisor.json
    # a baseline's prior phases take half its budget, so its 100- and 150-episode cells
    # are runs of their own (the 200-episode run's actor at episode 100 has not yet
    # imitated anything): half the demonstrations, or of the random/MPC/DAgger episodes
    advisor-jax train --preset physical --agent LfD --seeds 16 --eval-episodes 100 \\
        --episodes 100 --hp demo_episodes=50 --out runs/table2_short/LfD_e100
    python experiments/table2.py --runs runs/table2 runs/table2_short \\
        --advisor runs/table2/advisor.json --out results/table2

Every finished run under ``--runs`` evaluated in the physical arena is one agent type (a
shorter run of a type gives that budget's cell, marked ‡, in place of the kept actor); its
success at each budget is the mean ± Student-t 95 % interval over seeds, and ATD3+AfDP (the
paper's best) is compared with every other type seed by seed (``table1.paired_difference``:
same seeds, same evaluation episodes). Table 3 pools every collision episode of an agent
type's seeds at the largest budget: mean ± standard deviation of the collision speed, as the
paper reports it, from each agent's mean, spread (``collision_speed_sd``) and count; the
paper's Table 3 claim (AfP agents collide slower) is tested seed by seed on each seed's mean
collision speed. A type that never collides (the advisor) has no collision speed: its row
says so instead of giving a number.

Every row's settings are shown: what its preset changes from ``paper`` (``physical``: the
buffer, batch, ATD3's policy delay d = 3, ...), what it changes from its preset (the
``stable`` switches) and the learner's effective delay. A baseline's prior-knowledge phases
(LfD, MCP+MF: N_T episodes counted in the budget) end at or after a small budget, so that
budget's actor has had no RL (LfD's not even its imitation, which runs after its last
demonstration episode): such cells are marked †. The advisor's own evaluation command,
device and date are read from ``<advisor>_command.json`` beside ``--advisor`` if present.
Writes ``table2.md``, ``table2.json`` and ``table2.png`` into ``--out``.
"""

from __future__ import annotations

import argparse
import json
import math
import sys
from pathlib import Path

import common
import numpy as np
import table1

from advisor_jax.agent.baselines import prior_episodes
from advisor_jax.agent.config import (
    PRESETS,
    AgentConfig,
    HParams,
    TrainConfig,
    hparams_from_row,
    preset,
    train_config_from_dict,
)
from advisor_jax.agent.settings import preset_values
from advisor_jax.fileio import atomic_write_json
from advisor_jax.training.plots import save_png
from advisor_jax.training.reporting import mean_ci95

ARENA = "physical"
PAPER_TABLE2 = {  # success % at 100 / 150 / 200 training episodes (paper Table 2)
    "DDPG": (30.7, 39.0, 45.0),
    "ADDPG": (33.0, 43.3, 48.3),
    "ADDPG+AfDP": (45.0, 59.3, 70.3),
    "ATD3+AfDP": (48.3, 69.3, 75.3),
    "LfD": (37.0, 48.3, 60.7),
    "MCP+MF": (34.7, 45.3, 53.3),
}
PAPER_BUDGETS = (100, 150, 200)
PAPER_TABLE3 = {  # collision speed m/s, mean ± sd, agents trained for 200 episodes
    "Advisor": (0.36, 0.24),
    "DDPG": (0.43, 0.26),
    "ADDPG": (0.38, 0.21),
    "ADDPG+AfDP": (0.21, 0.16),
    "ATD3+AfDP": (0.15, 0.13),
    "LfD": (0.19, 0.21),
    "MCP+MF": (0.35, 0.25),
}
BEST = "ATD3+AfDP"  # the paper's best agent type in Tables 2 and 3
# beta=1, beta_normalize=1, clip_actor_target=1, clip_q_target=1
STABLE_SWITCHES = preset_values(HParams, "stable", changed_only=True)
NO_RL = "†"  # a budget the baseline's prior-knowledge phases fill: no RL episode yet
SEPARATE = "‡"  # a budget given by a separate, shorter run of the type (load_rows)
NO_RL_ACTOR = {  # what a baseline's actor is when its budget ends with its prior phases
    "lfd": "LfD's imitation runs after its last demonstration episode, so its actor there is "
    "the untrained initial one",
    "mcp": "MCP+MF's actor there is its imitation of the MPC before its last DAgger refit",
}


def pooled_collision_speed(evaluation: dict) -> dict:
    """Mean ± sd of the collision speed over every collision episode of all agents of one
    evaluation (``{"collision": [rate], "collision_speed": [mean], "collision_speed_sd":
    [sd], "episodes": n}``), and the number of collisions: the pooled moments of the
    agents' own (an agent without collisions adds nothing)."""
    n_episodes = evaluation["episodes"]
    counts, means, sds = [], [], []
    for rate, mean, sd in zip(
        evaluation["collision"],
        evaluation["collision_speed"],
        evaluation.get("collision_speed_sd") or [None] * len(evaluation["collision"]),
        strict=True,
    ):
        if rate is None or mean is None:
            continue
        count = round(rate * n_episodes)
        if count == 0:
            continue
        if sd is None:
            raise ValueError(
                "collision_speed_sd missing from an evaluation with collisions: re-evaluate "
                "the run with this version (experiments/reevaluate.py)"
            )
        counts.append(count)
        means.append(mean)
        sds.append(sd)
    total = sum(counts)
    if total == 0:
        return {"collisions": 0, "mean": None, "sd": None}
    c, m, s = (np.asarray(x, np.float64) for x in (counts, means, sds))
    mean = float(np.sum(c * m) / total)
    sd = float(np.sqrt(np.sum(c * (s**2 + (m - mean) ** 2)) / total))
    return {"collisions": total, "mean": mean, "sd": sd}


def load_rows(roots: list[Path]) -> tuple[list[dict], list[str]]:
    """One row per agent type found under ``roots``: per budget its per-seed success
    (``by_budget``) and evaluation. The type's longest run gives the row and its kept actors
    the smaller budgets; a run of the same type with a smaller N_total gives that budget
    instead (``separate``): for a baseline whose prior phases scale with the budget, the
    longer run's actor at that episode is not what a run of that length ends with. Runs not
    trained and evaluated in the physical arena, and a second run of a type at a budget
    already found, are left out with a note."""
    found: dict[str, list[tuple[Path, dict]]] = {}
    notes = []
    for root in roots:
        runs, left_out = common.finished_runs(root)
        notes += left_out
        for run_dir, summary in runs:
            if summary["config"].get("arena") != ARENA or ARENA not in (
                summary.get("evaluation") or {}
            ):
                notes.append(f"{run_dir}: not trained and evaluated in the {ARENA} arena, left out")
                continue
            found.setdefault(summary["agent"], []).append((run_dir, summary))
    rows = []
    for runs in found.values():
        runs.sort(key=lambda run: -run[1]["config"]["episodes"])  # the longest first
        row = _row(*runs[0])
        for run_dir, summary in runs[1:]:
            n = summary["config"]["episodes"]
            if n in row["separate"] or n == row["settings"]["episodes"]:
                notes.append(
                    f"{run_dir}: a second {row['agent']} run of {n} episodes (first: "
                    f"{row['separate'].get(n, {}).get('dir', row['dir'])}), left out"
                )
                continue
            short = _row(run_dir, summary)
            row["separate"][n] = {
                "dir": run_dir,
                "command": short["command"],
                "settings": short["settings"],
                "prior_episodes": short["prior_episodes"],
                "kept_actor": budget_stats(row, n),  # what it replaces, if anything
            }
            row["evaluation"][n] = short["evaluation"][n]
            row["by_budget"][n] = short["by_budget"][n]
        row["evaluation"] = dict(sorted(row["evaluation"].items()))
        rows.append(row)
    order = list(PAPER_TABLE2)
    ranked = sorted(rows, key=lambda r: (order.index(r["agent"]) if r["agent"] in order
                                         else len(order), r["agent"]))  # fmt: skip
    return ranked, notes


def _row(run_dir: Path, summary: dict) -> dict:
    """One run's row: its final evaluation at its N_total and its kept actors' at theirs."""
    budgets = {summary["config"]["episodes"]: summary["evaluation"][ARENA]}
    for n, ev in (summary.get("evaluation_at_episode") or {}).items():
        if ARENA in ev:
            budgets[int(n)] = ev[ARENA]
    seeds = [row["seed"] for row in summary["agents"]]
    command_file = run_dir / "command.json"
    command = json.loads(command_file.read_text()) if command_file.is_file() else {}
    return {
        "agent": summary["agent"],
        "dir": run_dir,
        "settings": common.preset_differences(summary, summary["agents"][0]),
        "seeds": seeds,
        **learner_settings(summary),
        "device": summary.get("device", "?"),
        "machine": command.get("machine"),
        "date": summary.get("created", "?")[:10],
        "command": command.get("command"),
        "evaluation": dict(sorted(budgets.items())),
        "by_budget": {
            n: {s: v for s, v in zip(seeds, ev["success"], strict=True) if v is not None}
            for n, ev in budgets.items()
        },
        "separate": {},
    }


def learner_settings(summary: dict) -> dict:
    """What a run's agents learn with beyond the preset differences: the learner (``algo``),
    its effective policy delay d (actor and targets every d critic updates; 1 for the DDPG
    family, whatever ``policy_delay`` says) and, for a baseline, its kind and the episodes
    its prior-knowledge phases take before RL (N_T, counted in the budget)."""
    agent = train_config_from_dict(summary["config"]).agent
    out = {"algo": agent.algo, "delay": agent.delay, "afp": agent.advisor_policy,
           "baseline": None, "prior_episodes": None}  # fmt: skip
    if agent.baseline is not None:
        hp = hparams_from_row(agent, summary["agents"][0])
        out["baseline"] = agent.baseline.kind
        out["prior_episodes"] = float(prior_episodes(agent.baseline, hp)[0])
    return out


def no_rl(row: dict, budget: int) -> bool:
    """The baseline's prior-knowledge phases take all of ``budget``: no RL episode yet."""
    prior = row["separate"].get(budget, row)["prior_episodes"]
    return prior is not None and budget <= prior


def preset_text(name: str) -> str:
    """What preset ``name`` changes from ``paper`` (``policy_delay 4→3``, ...)."""
    if name == "paper" or name not in PRESETS:
        return ""
    static, hp = preset(name)
    base_static, base_hp = preset("paper")
    agent_kw, train_kw, hp_kw = (
        preset_values(cls, name, changed_only=True) for cls in (AgentConfig, TrainConfig, HParams)
    )
    changed = [(k, static.agent, base_static.agent) for k in agent_kw]
    changed += [(k, static, base_static) for k in train_kw]
    changed += [(k, hp, base_hp) for k in hp_kw]
    parts = [
        f"{k} {common.setting_text(getattr(base, k))}→{common.setting_text(getattr(ours, k))}"
        for k, ours, base in changed
    ]
    return ", ".join(parts)


def collision_speed_by_seed(evaluation: dict, seeds: list) -> dict:
    """Each seed's mean collision speed (seeds without a collision left out)."""
    return {
        s: v
        for s, rate, v in zip(seeds, evaluation["collision"], evaluation["collision_speed"],
                              strict=True)
        if v is not None and rate
    }  # fmt: skip


def afp_collision_comparisons(rows: list[dict]) -> list[dict]:
    """Table 3's claim: each AfP type minus each type without AfP (baselines included), in
    each seed's mean collision speed (m/s), paired by the seeds where both collided; Student-t
    95 % interval; ``holds`` when it lies below 0 (the AfP type collides slower)."""
    afp = [r for r in rows if r["afp"]]
    other = [r for r in rows if not r["afp"]]
    out = []
    for a in afp:
        for b in other:
            sa, sb = a["collision_by_seed"], b["collision_by_seed"]
            seeds = sorted(set(sa) & set(sb))
            if len(seeds) < 2:
                continue
            mean, half = mean_ci95([sa[k] - sb[k] for k in seeds])
            verdict = "not resolved"
            if np.isfinite(half) and mean + half < 0:
                verdict = "holds"
            elif np.isfinite(half) and mean - half > 0:
                verdict = "reversed"
            out.append({"afp": a["agent"], "other": b["agent"], "seeds": len(seeds),
                        "mean": mean, "half": half, "verdict": verdict})  # fmt: skip
    return out


def budget_stats(row: dict, budget: int) -> dict | None:
    by_seed = row["by_budget"].get(budget)
    if by_seed is None:
        return None
    mean, half = mean_ci95(list(by_seed.values()))
    return {"seeds": len(by_seed), "mean": 100 * mean, "half": 100 * half}


def versus_best(rows: list[dict], budget: int) -> list[dict]:
    """ATD3+AfDP minus every other type at ``budget``, seed by seed (success points)."""
    best = next((r for r in rows if r["agent"] == BEST), None)
    if best is None:
        return []
    out = []
    for r in rows:
        if r is best or budget not in r["by_budget"] or budget not in best["by_budget"]:
            continue
        diff = table1.paired_difference(
            {"by_seed": {ARENA: best["by_budget"][budget]}},
            {"by_seed": {ARENA: r["by_budget"][budget]}},
            ARENA,
        )
        if diff is not None:
            out.append({"other": r["agent"], "budget": budget, **diff})
    return out


def _cell(stats: dict | None) -> str:
    if stats is None or math.isnan(stats["mean"]):
        return "–"
    half = "" if math.isnan(stats["half"]) else f" ± {stats['half']:.1f}"
    return f"{stats['mean']:.1f}{half} %"


def _separate_settings(run: dict) -> str:
    """A separate run's settings beyond its preset and the stable switches, and its prior
    phases' length."""
    own = {k: v for k, v in run["settings"].items()
           if k not in ("preset", "episodes", *STABLE_SWITCHES)}  # fmt: skip
    text = ", ".join(f"{k}={common.setting_text(v)}" for k, v in own.items()) or "same settings"
    prior = run["prior_episodes"]
    return text + (f", prior phases {prior:g} episodes" if prior is not None else "")


def _settings(settings: dict) -> str:
    """A row's settings beyond its preset, the ``stable`` switches named as such."""
    extra = {k: v for k, v in settings.items() if k not in ("preset", "episodes")}
    stable = all(
        k in extra and math.isclose(extra[k], v, rel_tol=1e-6) for k, v in STABLE_SWITCHES.items()
    )
    text = ", ".join(f"{k}={common.setting_text(v)}" for k, v in extra.items())
    if stable:
        text += " (the `stable` preset's switches)"
    return text or "none"


def _delay(row: dict) -> str:
    """The learner's effective policy delay d, and the paper's where the preset changes it."""
    if row["delay"] == 1:
        return "1 (DDPG family: no delay)"
    name = row["settings"]["preset"]
    paper = preset("paper", row["agent"])[0].agent.policy_delay
    ours = preset(name, row["agent"])[0].agent.policy_delay if name in PRESETS else paper
    source = f" (`{name}`; `paper`: {paper})" if ours != paper and row["delay"] == ours else ""
    return f"{row['delay']}{source}"


def _speed(mean, sd) -> str:
    return "none: no collision" if mean is None else f"{mean:.2f} ± {sd:.2f}"


def plot(
    rows: list[dict], budgets: list[int], advisor: dict | None, path: Path, title: str = ""
) -> None:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, (left, right) = plt.subplots(1, 2, figsize=(13, 5.2), constrained_layout=True)
    if title:
        fig.suptitle(title, fontsize=9)
    colors = plt.rcParams["axes.prop_cycle"].by_key()["color"]
    step = (budgets[-1] - budgets[0]) / max(len(budgets) - 1, 1) if len(budgets) > 1 else 50
    width = 0.6 * step / max(len(rows), 1)
    flagged, separate = [], []
    for i, r in enumerate(rows):
        color = colors[i % len(colors)]
        offset = (i - (len(rows) - 1) / 2) * width
        for j, n in enumerate(budgets):
            values = [100 * v for v in r["by_budget"].get(n, {}).values()]
            common.seeds_with_ci(
                left, n + offset, values, color, label=None if j else r["agent"], width=width * 0.6
            )
            marks = (NO_RL if values and no_rl(r, n) else "") + (
                SEPARATE if values and n in r["separate"] else ""
            )
            if marks:
                left.annotate(marks, (n + offset, max(values)), xytext=(0, 4),
                              textcoords="offset points", ha="center", color=color)  # fmt: skip
            if NO_RL in marks:
                flagged.append(r["agent"])
            if SEPARATE in marks:
                separate.append(r["agent"])
        paper = PAPER_TABLE2.get(r["agent"])
        if paper:
            left.plot(PAPER_BUDGETS, paper, ls=":", marker="x", color=color, lw=1)
    left.plot([], [], ls=":", marker="x", color="0.3", label="paper (Table 2)")
    left.set_xticks(budgets)
    left.set_xlabel("training episodes")
    left.set_ylabel(f"success in the {ARENA} arena (%)")
    left.set_ylim(-3, 103)
    left.grid(alpha=0.3)
    left.legend(fontsize=8, ncol=2, loc="lower right")
    left.set_title("Table 2: per-seed success (dots), mean ± 95 % CI", fontsize=10)
    notes = []
    if flagged:
        notes.append(f"{NO_RL} {', '.join(dict.fromkeys(flagged))}: prior-knowledge phases "
                     "only at this budget, no RL yet")  # fmt: skip
    if separate:
        notes.append(f"{SEPARATE} {', '.join(dict.fromkeys(separate))}: a separate run of "
                     "this many episodes")  # fmt: skip
    if notes:
        left.set_xlabel("training episodes\n" + "\n".join(notes), fontsize=9)
    names, ours, spreads, papers, counts = [], [], [], [], []
    entries = ([("Advisor", advisor)] if advisor else []) + [
        (r["agent"], r["collision"]) for r in rows
    ]
    for name, c in entries:
        names.append(name)
        ours.append(np.nan if c["mean"] is None else c["mean"])
        spreads.append(0.0 if c["sd"] is None else c["sd"])
        papers.append(PAPER_TABLE3.get(name, (np.nan, np.nan)))
        counts.append((c["collisions"], c.get("episodes")))
    x = np.arange(len(names))
    right.bar(x - 0.2, ours, 0.4, yerr=spreads, capsize=3, label="ours (mean ± sd)")
    right.bar(
        x + 0.2,
        [p[0] for p in papers],
        0.4,
        yerr=[p[1] for p in papers],
        capsize=3,
        color="0.7",
        label="paper (Table 3)",
    )
    for xi, mean, sd, (n, of) in zip(x, ours, spreads, counts, strict=True):
        of_text = f"/{of}" if of else ""
        if np.isnan(mean):  # no collision: no speed to draw
            right.text(xi - 0.2, 0.02, f"no collision (0{of_text})", rotation=90,
                       ha="center", va="bottom", fontsize=8, color="C0")  # fmt: skip
        else:
            right.text(xi - 0.2, mean + sd + 0.02, f"n={n}", ha="center", fontsize=7)
    tops = [m + d for m, d in zip(ours, spreads, strict=True)] + [m + d for m, d in papers]
    right.set_ylim(0, 1.3 * np.nanmax([*tops, 0.1]))  # room for the counts and the legend
    right.set_xticks(x, names, rotation=20, fontsize=8)
    right.set_ylabel("collision speed (m/s)")
    right.grid(alpha=0.3, axis="y")
    right.legend(fontsize=8, ncol=2, loc="upper center")
    right.set_title(
        f"Table 3: collision speed, {budgets[-1]} episodes (n = collisions pooled over seeds)",
        fontsize=10,
    )
    save_png(fig, path)


def load_advisor(path: Path) -> dict:
    """``advisor-jax evaluate --policy advisor --arena physical --json`` output as Table 3's
    first row, with its command, device and date from ``<stem>_command.json`` if present."""
    a = json.loads(path.read_text())
    if a.get("arena", ARENA) != ARENA:
        sys.exit(f"--advisor {path}: evaluated in {a['arena']!r}, not {ARENA!r}")
    command_file = path.with_name(f"{path.stem}_command.json")
    command = json.loads(command_file.read_text()) if command_file.is_file() else {}
    return {
        "collisions": round(a["collision_rate"] * a["episodes"]),
        "mean": a.get("mean_collision_speed"),
        "sd": a.get("collision_speed_sd"),
        "success": a["success_rate"],
        "episodes": a["episodes"],
        "command": command.get("command"),
        "device": command.get("device"),
        "machine": command.get("machine"),
        "date": (command.get("created") or "")[:10] or None,
    }


def _joined(values) -> str:
    return ", ".join(sorted({str(v) for v in values if v})) or "?"


def summarize(args) -> None:
    rows, notes = load_rows(args.runs)
    if not rows:
        sys.exit(f"no finished {ARENA}-arena runs under {', '.join(map(str, args.runs))}")
    budgets = sorted({n for r in rows for n in r["by_budget"]})
    final = budgets[-1]
    for r in rows:
        final_eval = r["evaluation"].get(final)
        r["collision"] = (
            pooled_collision_speed(final_eval)
            if final_eval
            else {"collisions": 0, "mean": None, "sd": None}
        )
        r["collision"]["episodes"] = (
            final_eval["episodes"] * len(r["seeds"]) if final_eval else None
        )
        r["collision_by_seed"] = (
            collision_speed_by_seed(final_eval, r["seeds"]) if final_eval else {}
        )
    advisor = load_advisor(args.advisor) if args.advisor is not None else None
    comparisons = [c for n in budgets for c in versus_best(rows, n)]
    by_agent = {r["agent"]: r for r in rows}
    for c in comparisons:
        c["no_rl"] = no_rl(by_agent[c["other"]], c["budget"])
    speed_comparisons = afp_collision_comparisons(rows)
    args.out.mkdir(parents=True, exist_ok=True)

    eval_episodes = sorted({ev["episodes"] for r in rows for ev in r["evaluation"].values()})
    seeds = sorted({st["seeds"] for r in rows for n in budgets if (st := budget_stats(r, n))})
    presets = sorted({r["settings"]["preset"] for r in rows})
    beyond = sorted({_settings(r["settings"]) for r in rows})
    device = _joined(r["device"] for r in rows)
    dates = _joined(r["date"] for r in rows)
    machines = _joined(r["machine"] for r in rows)
    machines = "" if machines == "?" else f" ({machines})"
    title = (
        f"{', '.join(f'--preset {p}' for p in presets)}"
        + (f" + {beyond[0]}" if len(beyond) == 1 and beyond[0] != "none" else "")
        + f"; {', '.join(map(str, seeds))} seeds × {', '.join(map(str, eval_episodes))} "
        f"evaluation episodes; {device}, {dates}"
    )
    plot(rows, budgets, advisor, args.out / "table2.png", title=title.replace("`", ""))

    summarize_cmd = common.command_line(
        "experiments/table2.py",
        [
            "--runs",
            *args.runs,
            *(["--advisor", args.advisor] if args.advisor else []),
            "--out",
            args.out,
        ],
    )
    flagged = [r for r in rows if any(no_rl(r, n) for n in budgets)]
    separate = [(r, n, x) for r in rows for n, x in sorted(r["separate"].items())]
    table2_rows = []
    for r in rows:
        paper = PAPER_TABLE2.get(r["agent"])
        table2_rows.append(
            (
                r["agent"],
                *(
                    _cell(budget_stats(r, n))
                    + (f" {NO_RL}" if no_rl(r, n) else "")
                    + (f" {SEPARATE}" if n in r["separate"] else "")
                    for n in budgets
                ),
                " / ".join(f"{v:.1f}" for v in paper) if paper else "–",
            )
        )
    table3 = []
    if advisor:
        p = PAPER_TABLE3["Advisor"]
        table3.append(
            ("Advisor", _speed(advisor["mean"], advisor["sd"]),
             f"{advisor['collisions']} of {advisor['episodes']}", f"{p[0]:.2f} ± {p[1]:.2f}")
        )  # fmt: skip
    for r in rows:
        p = PAPER_TABLE3.get(r["agent"])
        c = r["collision"]
        table3.append(
            (r["agent"], _speed(c["mean"], c["sd"]), f"{c['collisions']} of {c['episodes']}",
             f"{p[0]:.2f} ± {p[1]:.2f}" if p else "–")
        )  # fmt: skip
    lines = [
        "# Paper Tables 2 and 3: the physical arena",
        "",
        f"Trained on {device}{machines}, {dates}; seeds per "
        f"agent type: {', '.join(map(str, seeds))}. Every type is scored on the same "
        f"{', '.join(map(str, eval_episodes))} episodes of the {ARENA} arena per seed "
        "(deterministic actor). The smaller budgets are the actors kept at that episode of "
        "the same runs (`--snapshot-episodes`): what a run of that many episodes ends with"
        + (f", except the cells marked {SEPARATE} (separate runs, below)." if separate else "."),
        "",
        "Settings of every row: "
        + "; ".join(
            f"`--preset {p}`" + (f" (= `paper` with {t})" if (t := preset_text(p)) else "")
            for p in presets
        )
        + (f"; beyond it: {beyond[0]}" if len(beyond) == 1 else "")
        + (
            ": scale-free β = 1, Â clipped to the action box, TD target clipped to the "
            "arena's return bounds"
            if any("`stable`" in b for b in beyond)
            else ""
        )
        + ". Per row (learner, effective policy delay d, prior-knowledge episodes) under "
        "Settings and commands below.",
        "",
        "## Table 2: success in the physical arena",
        "",
        "Mean ± half-width of the Student-t 95 % interval over seeds; the paper's values "
        "(100 test episodes of one agent per type) in the last column.",
        "",
        *common.markdown_table(
            ["agent", *(f"{n} episodes" for n in budgets), "paper (100 / 150 / 200)"],
            table2_rows,
            align="l" + "r" * (len(budgets) + 1),
        ),
        "",
    ]
    if separate:
        lines += [
            f"{SEPARATE} A separate run of that many episodes: a baseline's prior-knowledge "
            "phases take half of its budget (the paper's 50 % rule), so the longer run's actor "
            "at that episode, still in or just past its prior phases, is not what a run of that "
            "length ends with. "
            + "; ".join(
                f"{r['agent']} at {n}: {_separate_settings(x)}"
                + (
                    f" (the {r['settings']['episodes']}-episode run's actor at episode {n}: "
                    f"{_cell(x['kept_actor'])})"
                    if x["kept_actor"]
                    else ""
                )
                for r, n, x in separate
            )
            + ".",
            "",
        ]
    if flagged:
        lines += [
            f"{NO_RL} No RL yet: "
            + "; ".join(
                f"{r['agent']}'s prior-knowledge phases take its first "
                f"{r['prior_episodes']:g} episodes (N_T, counted in the budget)"
                for r in flagged
            )
            + ". The actor kept at a budget is the one at the end of its last episode, before "
            "the offline steps that follow: "
            + "; ".join(NO_RL_ACTOR.get(r["baseline"], r["agent"]) for r in flagged)
            + ". These cells measure the prior phases, not the agent trained for that budget "
            "as the paper's baselines were.",
            "",
        ]
    if comparisons:
        lines += [
            f"{BEST} (the paper's best) minus each other type, success points, seed by seed "
            "(mean ± 95 % CI); `holds` when the interval lies above 0, `reversed` below 0:",
            "",
            *common.markdown_table(
                ["other type", "episodes", "paired seeds", f"{BEST} − other", "verdict"],
                [
                    (
                        c["other"],
                        c["budget"],
                        c["seeds"],
                        f"{c['mean']:+.1f} ± {c['half']:.1f}",
                        c["verdict"] + (f" {NO_RL}" if c["no_rl"] else ""),
                    )
                    for c in comparisons
                ],  # fmt: skip
                align="lrrrl",
            ),
            "",
        ]
    lines += [
        f"## Table 3: collision speed, agents trained for {final} episodes",
        "",
        "Mean ± standard deviation over every collision episode of the type's seeds (the "
        "paper's measure), and how many collisions of how many evaluation episodes that is.",
        "",
        *common.markdown_table(
            ["agent", "collision speed (m/s)", "collisions", "paper (m/s)"], table3, align="lrrr"
        ),
        "",
    ]
    if advisor and advisor["collisions"] == 0:
        lines += [
            f"The advisor never collided in its {advisor['episodes']} {ARENA}-arena episodes "
            f"(success {100 * advisor['success']:.1f} %, the rest timeouts), so it has no "
            f"collision speed to compare with the paper's "
            f"{PAPER_TABLE3['Advisor'][0]:.2f} ± {PAPER_TABLE3['Advisor'][1]:.2f} m/s.",
            "",
        ]
    if speed_comparisons:
        lines += [
            "The paper's Table 3 claim, AfP agents collide slower: each AfP type minus each type "
            "without AfP, in each seed's mean collision speed (m/s), paired by the seeds where "
            "both collided (mean ± 95 % CI); `holds` when the interval lies below 0:",
            "",
            *common.markdown_table(
                ["AfP type", "other type", "paired seeds", "difference (m/s)", "verdict"],
                [
                    (
                        c["afp"],
                        c["other"],
                        c["seeds"],
                        f"{c['mean']:+.2f} ± {c['half']:.2f}",
                        c["verdict"],
                    )
                    for c in speed_comparisons
                ],  # fmt: skip
                align="llrrl",
            ),
            "",
        ]
    lines += [
        "![Table 2 per seed and Table 3](table2.png)",
        "",
        "## Settings and commands",
        "",
        *common.markdown_table(
            [
                "agent",
                "preset",
                "episodes",
                "learner",
                "policy delay d",
                "prior-knowledge episodes",
                "beyond the preset",
            ],
            [
                (
                    r["agent"],
                    r["settings"]["preset"],
                    r["settings"]["episodes"],
                    r["algo"],
                    _delay(r),
                    "–" if r["prior_episodes"] is None else f"{r['prior_episodes']:g}",
                    _settings(r["settings"]),
                )
                for r in rows
            ],
            align="llrlrrl",
        ),  # fmt: skip
        "",
        f"Summary: `{summarize_cmd}`. Training commands:",
        "",
        *(f"- `{r['command']}`" for r in rows if r["command"]),
        *(f"- `{x['command']}` ({SEPARATE})" for _, _, x in separate if x["command"]),
    ]
    if advisor and advisor["command"]:
        lines += [
            "",
            f"Advisor evaluation ({advisor['device'] or '?'}, {advisor['date'] or '?'}): "
            f"`{advisor['command']}`",
        ]
    if notes:
        lines += ["", "Notes:", "", *(f"- {n}" for n in notes)]
    common.write_markdown(args.out / "table2.md", lines)
    record = {
        "budgets": budgets,
        "agents": {
            r["agent"]: {
                "success": {str(n): list(r["by_budget"][n].values()) for n in r["by_budget"]},
                "collision_speed": r["collision"],
                "settings": r["settings"],
                "learner": {k: r[k] for k in ("algo", "delay", "afp", "baseline")},
                "prior_episodes": r["prior_episodes"],
                "no_rl_budgets": [n for n in budgets if no_rl(r, n)],
                "separate_runs": {
                    str(n): {
                        "dir": str(x["dir"]),
                        "command": x["command"],
                        "settings": x["settings"],
                        "prior_episodes": x["prior_episodes"],
                        "kept_actor_replaced": x["kept_actor"],
                    }
                    for n, x in sorted(r["separate"].items())
                },  # fmt: skip
                "paper": {
                    "success": PAPER_TABLE2.get(r["agent"]),
                    "collision_speed": PAPER_TABLE3.get(r["agent"]),
                },
            }
            for r in rows
        },
        "presets": {p: preset_text(p) for p in presets},
        "advisor": advisor,
        "versus_best": comparisons,
        "afp_collision_speed": speed_comparisons,
        "provenance": {
            "summarize": summarize_cmd,
            "commands": [r["command"] for r in rows]
            + [x["command"] for _, _, x in separate if x["command"]],
            "device": device,
            "machines": sorted({r["machine"] for r in rows if r["machine"]}),
            "trained": dates,
            "notes": notes,
            "date": common.provenance(with_jax=False)["date"],
        },
    }
    atomic_write_json(args.out / "table2.json", record)


def main() -> None:
    parser = argparse.ArgumentParser(
        description=__doc__.split("\n\n")[0], formatter_class=argparse.RawDescriptionHelpFormatter
    )
    parser.add_argument(
        "--runs", type=Path, nargs="+", required=True,
        help="folders of finished physical-arena runs, one run per agent type",
    )  # fmt: skip
    parser.add_argument(
        "--advisor", type=Path, default=None,
        help="`advisor-jax evaluate --policy advisor --arena physical --json` output (Table 3's "
        "advisor row)",
    )  # fmt: skip
    parser.add_argument("--out", type=Path, default=Path("results/table2"))
    summarize(parser.parse_args())


if __name__ == "__main__":
    main()
