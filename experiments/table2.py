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
    python experiments/table2.py --runs runs/table2 --advisor runs/table2/advisor.json \\
        --out results/table2

Every finished run under ``--runs`` evaluated in the physical arena is one agent type; its
success at each budget is the mean ± Student-t 95 % interval over seeds, and ATD3+AfDP (the
paper's best) is compared with every other type seed by seed (``table1.paired_difference``:
same seeds, same evaluation episodes). Table 3 pools every collision episode of an agent
type's seeds at the largest budget: mean ± standard deviation of the collision speed, as the
paper reports it, from each agent's mean, spread (``collision_speed_sd``) and count.
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
    (``by_seed``) and evaluation; runs not trained and evaluated in the physical arena, and
    a second run of a type already found, are left out with a note."""
    rows: dict[str, dict] = {}
    notes = []
    for root in roots:
        runs, left_out = common.finished_runs(root)
        notes += left_out
        for run_dir, summary in runs:
            agent = summary["agent"]
            final = (summary.get("evaluation") or {}).get(ARENA)
            if summary["config"].get("arena") != ARENA or final is None:
                notes.append(f"{run_dir}: not trained and evaluated in the {ARENA} arena, left out")
                continue
            if agent in rows:
                notes.append(
                    f"{run_dir}: a second {agent} run (first: {rows[agent]['dir']}), left out"
                )
                continue
            budgets = {summary["config"]["episodes"]: final}
            for n, ev in (summary.get("evaluation_at_episode") or {}).items():
                if ARENA in ev:
                    budgets[int(n)] = ev[ARENA]
            seeds = [row["seed"] for row in summary["agents"]]
            settings = common.preset_differences(summary, summary["agents"][0])
            command_file = run_dir / "command.json"
            rows[agent] = {
                "agent": agent,
                "dir": run_dir,
                "settings": settings,
                "device": summary.get("device", "?"),
                "date": summary.get("created", "?")[:10],
                "command": json.loads(command_file.read_text()).get("command")
                if command_file.is_file()
                else None,
                "evaluation": dict(sorted(budgets.items())),
                "by_budget": {
                    n: {s: v for s, v in zip(seeds, ev["success"], strict=True) if v is not None}
                    for n, ev in budgets.items()
                },
            }
    order = list(PAPER_TABLE2)
    ranked = sorted(rows.values(), key=lambda r: (order.index(r["agent"]) if r["agent"] in order
                                                  else len(order), r["agent"]))  # fmt: skip
    return ranked, notes


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


def _settings(settings: dict) -> str:
    return ", ".join(f"{k}={common.setting_text(v)}" for k, v in settings.items())


def _speed(mean, sd) -> str:
    return "–" if mean is None else f"{mean:.2f} ± {sd:.2f}"


def plot(rows: list[dict], budgets: list[int], advisor: dict | None, path: Path) -> None:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, (left, right) = plt.subplots(1, 2, figsize=(13, 4.8), constrained_layout=True)
    colors = plt.rcParams["axes.prop_cycle"].by_key()["color"]
    step = (budgets[-1] - budgets[0]) / max(len(budgets) - 1, 1) if len(budgets) > 1 else 50
    width = 0.6 * step / max(len(rows), 1)
    for i, r in enumerate(rows):
        color = colors[i % len(colors)]
        offset = (i - (len(rows) - 1) / 2) * width
        for j, n in enumerate(budgets):
            values = [100 * v for v in r["by_budget"].get(n, {}).values()]
            common.seeds_with_ci(
                left, n + offset, values, color, label=None if j else r["agent"], width=width * 0.6
            )
        paper = PAPER_TABLE2.get(r["agent"])
        if paper:
            left.plot(PAPER_BUDGETS, paper, ls=":", marker="x", color=color, lw=1)
    left.plot([], [], ls=":", marker="x", color="0.3", label="paper (Table 2)")
    left.set_xticks(budgets)
    left.set_xlabel("training episodes")
    left.set_ylabel(f"success in the {ARENA} arena (%)")
    left.set_ylim(-3, 103)
    left.grid(alpha=0.3)
    left.legend(fontsize=8, ncol=2)
    left.set_title("Table 2: per-seed success (dots), mean ± 95 % CI")
    names, ours, spreads, papers = [], [], [], []
    entries = ([("Advisor", advisor)] if advisor else []) + [
        (r["agent"], r["collision"]) for r in rows
    ]
    for name, c in entries:
        names.append(name)
        ours.append(np.nan if c["mean"] is None else c["mean"])
        spreads.append(0.0 if c["sd"] is None else c["sd"])
        papers.append(PAPER_TABLE3.get(name, (np.nan, np.nan)))
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
    right.set_xticks(x, names, rotation=20, fontsize=8)
    right.set_ylabel("collision speed (m/s)")
    right.grid(alpha=0.3, axis="y")
    right.legend(fontsize=8)
    right.set_title(f"Table 3: collision speed, {budgets[-1]} episodes")
    save_png(fig, path)


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
    advisor = None
    if args.advisor is not None:
        a = json.loads(args.advisor.read_text())
        if a.get("arena", ARENA) != ARENA:
            sys.exit(f"--advisor {args.advisor}: evaluated in {a['arena']!r}, not {ARENA!r}")
        count = round(a["collision_rate"] * a["episodes"])
        advisor = {
            "collisions": count,
            "mean": a.get("mean_collision_speed"),
            "sd": a.get("collision_speed_sd"),
            "success": a["success_rate"],
            "episodes": a["episodes"],
        }
    comparisons = [c for n in budgets for c in versus_best(rows, n)]
    args.out.mkdir(parents=True, exist_ok=True)
    plot(rows, budgets, advisor, args.out / "table2.png")

    eval_episodes = sorted({ev["episodes"] for r in rows for ev in r["evaluation"].values()})
    seeds = sorted({st["seeds"] for r in rows for n in budgets if (st := budget_stats(r, n))})
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
    table2_rows = []
    for r in rows:
        paper = PAPER_TABLE2.get(r["agent"])
        table2_rows.append(
            (
                r["agent"],
                *(_cell(budget_stats(r, n)) for n in budgets),
                " / ".join(f"{v:.1f}" for v in paper) if paper else "–",
            )
        )
    table3 = []
    if advisor:
        p = PAPER_TABLE3["Advisor"]
        table3.append(
            ("Advisor", _speed(advisor["mean"], advisor["sd"]), advisor["collisions"],
             f"{p[0]:.2f} ± {p[1]:.2f}")
        )  # fmt: skip
    for r in rows:
        p = PAPER_TABLE3.get(r["agent"])
        c = r["collision"]
        table3.append(
            (r["agent"], _speed(c["mean"], c["sd"]), c["collisions"],
             f"{p[0]:.2f} ± {p[1]:.2f}" if p else "–")
        )  # fmt: skip
    lines = [
        "# Paper Tables 2 and 3: the physical arena",
        "",
        f"Trained on {', '.join(sorted({r['device'] for r in rows}))}, "
        f"{', '.join(sorted({r['date'] for r in rows}))}; seeds per agent type: "
        f"{', '.join(map(str, seeds))}. Every type is scored on the same "
        f"{', '.join(map(str, eval_episodes))} episodes of the {ARENA} arena per seed "
        "(deterministic actor). The smaller budgets are the actors kept at that episode of "
        "the same runs (`--snapshot-episodes`): what a run of that many episodes ends with.",
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
    if comparisons:
        lines += [
            f"{BEST} (the paper's best) minus each other type, success points, seed by seed "
            "(mean ± 95 % CI); `holds` when the interval lies above 0:",
            "",
            *common.markdown_table(
                ["other type", "episodes", "paired seeds", f"{BEST} − other", "verdict"],
                [
                    (
                        c["other"],
                        c["budget"],
                        c["seeds"],
                        f"{c['mean']:+.1f} ± {c['half']:.1f}",
                        c["verdict"],
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
        "paper's measure), and how many collisions that is.",
        "",
        *common.markdown_table(
            ["agent", "collision speed (m/s)", "collisions", "paper (m/s)"], table3, align="lrrr"
        ),
        "",
        "![Table 2 per seed and Table 3](table2.png)",
        "",
        "Settings: " + "; ".join(f"{r['agent']}: {_settings(r['settings'])}" for r in rows) + ".",
        "",
        f"Summary: `{summarize_cmd}`. Training commands:",
        "",
        *(f"- `{r['command']}`" for r in rows if r["command"]),
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
                "paper": {
                    "success": PAPER_TABLE2.get(r["agent"]),
                    "collision_speed": PAPER_TABLE3.get(r["agent"]),
                },
            }
            for r in rows
        },
        "advisor": advisor,
        "versus_best": comparisons,
        "provenance": {
            "summarize": summarize_cmd,
            "commands": [r["command"] for r in rows],
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
