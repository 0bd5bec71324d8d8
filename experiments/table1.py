"""Paper Table 1 / Fig. 8 / Fig. 9: agent types × seeds, trained and evaluated alike.

    # train (one compile per agent type; every seed of a type is one vmapped program)
    python experiments/table1.py train --runs runs/table1 --preset paper --episodes 200 --seeds 4
    # the same agent types at other settings (applied to every type), into another --runs
    python experiments/table1.py train --runs runs/table1_chosen --seeds 16 \\
        --hp beta=1 --hp beta_normalize=1
    # aggregate into results/table1.md, .json and .png: the first --runs is the table of
    # table1.json, every further one (e.g. the literal-paper rows) a table of its own
    python experiments/table1.py summarize --runs runs/table1_chosen runs/table1 --out results

``train`` skips agent types that finished in --runs and resumes interrupted ones. Every
agent type is evaluated on the same 100 episodes per arena (same key: the first seed), so
the rows are paired. Cells are mean ± half-width of the Student-t 95 % interval over seeds;
the figure shows every seed. table1.json: ``{"seeds": N, "agents": {"ATD3+AfDP":
{"training": [per-seed success, 0..1], "validation": [...], "settings": {"preset", "episodes",
hyperparameters that differ from the preset}}, ...}}``; N is the fewest seeds of any agent
type, diverged seeds (no evaluation) are left out of the lists.
"""

from __future__ import annotations

import argparse
import dataclasses
import json
import sys
import warnings
from pathlib import Path

import common
import numpy as np

from advisor_jax.agent.config import PAPER_AGENTS, SWITCHES, HParams, preset
from advisor_jax.agent.settings import preset_values
from advisor_jax.fileio import atomic_write_json
from advisor_jax.training.plots import save_png
from advisor_jax.training.reporting import mean_ci95, moving_average
from envs import GOAL

PAPER_TABLE1 = {  # success, training / validation environment (paper Table 1)
    "DDPG": (72.2, 71.3),
    "ADDPG": (78.3, 77.1),
    "ADDPG+AfD": (81.3, 79.3),
    "ADDPG+AfP": (84.5, 83.0),
    "ADDPG+AfDP": (88.1, 85.2),
    "ATD3+AfDP": (90.8, 89.4),
    "LfD": (80.2, 80.7),
    "MCP+MF": (82.3, 80.1),
}
BASELINES = ("LfD", "MCP+MF")  # issue 19: the paper's two other ways of using prior knowledge
ORDER = (*PAPER_AGENTS, *BASELINES, "TD3", "ATD3", "ATD3+AfD")
ARENAS = ("training", "validation")
BLOCK = 50  # training episodes per column of the learning table
# The paper's claims as (better, worse) pairs: its Table 1 ordering, adjacent rows, then the
# effect of the advisor in policy updating (AfP) over the same agent without it.
PAPER_ORDERING = (
    ("ATD3+AfDP", "ADDPG+AfDP"),
    ("ADDPG+AfDP", "ADDPG+AfP"),
    ("ADDPG+AfP", "ADDPG+AfD"),
    ("ADDPG+AfD", "ADDPG"),
    ("ADDPG", "DDPG"),
)
AFP_EFFECTS = (("ADDPG+AfP", "ADDPG"), ("ADDPG+AfDP", "ADDPG+AfD"), ("ATD3+AfDP", "ATD3+AfD"))
# §6.2: "ATD3 + AfDP outperforms all other algorithms by a significant margin", the
# baselines included.
OVER_BASELINES = tuple(("ATD3+AfDP", b) for b in BASELINES)


def train(args) -> None:
    try:
        overrides = common.hp_overrides(args.hp)
    except ValueError as e:
        sys.exit(str(e))
    command = common.command_line("experiments/table1.py", sys.argv[1:])
    for agent in args.agents:
        cfg, hp = preset(args.preset, agent)
        cfg = dataclasses.replace(cfg, episodes=args.episodes or cfg.episodes)
        run_dir = args.runs / agent.replace("+", "_")
        how = common.train_or_resume(
            run_dir,
            cfg,
            dataclasses.replace(hp, **overrides),
            {},
            list(range(args.seed, args.seed + args.seeds)),
            eval_episodes=args.eval_episodes,
            eval_seed=args.seed,  # every agent type on the same episodes
            checkpoint_every=0,
            progress=False,
            meta={"preset": args.preset, "table1": {"hp": overrides, "command": command}},
        )
        print(f"{agent}: {how}", file=sys.stderr)
        if args.export:
            common.export_small_files(run_dir, args.export / run_dir.name)


def _fmt(mean: float, half: float) -> str:
    if np.isnan(mean):
        return "–"
    return f"{mean:.1f}" + ("" if np.isnan(half) else f" ± {half:.1f}")


def load_table(root: Path) -> list[dict]:
    """The finished agent types under ``root``, in Table 1's order: name, run dirs,
    run.json, settings, per-seed success per arena (0..1).

    Runs of one agent type at the same settings are one row with the seeds of all of them
    (e.g. seeds 0-15 and 16-31 trained as two populations); the same seed twice is an
    error. The same type at different settings gives a row per setting."""
    runs, notes = common.finished_runs(root)
    for note in notes:
        print(f"note: {note}", file=sys.stderr)
    pooled: dict[tuple[str, str], dict] = {}
    for run_dir, summary in runs:
        agent = summary["agent"]
        settings = [common.preset_differences(summary, row) for row in summary["agents"]]
        if any(s != settings[0] for s in settings):
            sys.exit(f"{run_dir}: its agents differ in more than the seed; not a Table 1 row")
        ev = summary["evaluation"]
        seeds = [row["seed"] for row in summary["agents"]]
        command_file = run_dir / "command.json"  # written beside runs made on the device tool
        command = (summary.get("table1") or {}).get("command") or (
            json.loads(command_file.read_text()).get("command") if command_file.exists() else None
        )
        key = (agent, json.dumps(settings[0], sort_keys=True))
        row = pooled.setdefault(
            key,
            {
                "agent": agent,
                "summary": summary,
                "settings": settings[0],
                "rank": ORDER.index(agent) if agent in ORDER else len(ORDER),
                "dirs": [], "summaries": [], "commands": [], "seeds": [],
                "by_seed": {a: {} for a in ARENAS if a in ev},
                "collision_speed": [], "diverged": 0,
            },
        )  # fmt: skip
        if twice := sorted(set(seeds) & set(row["seeds"])):
            sys.exit(f"{run_dir}: seeds {twice} of {agent} are also in {row['dirs']}")
        row["dirs"].append(run_dir)
        row["summaries"].append(summary)
        row["commands"] += [command] if command else []
        row["seeds"] += seeds
        row["diverged"] += len(summary.get("diverged", []))
        row["collision_speed"] += [v for v in ev["training"]["collision_speed"] if v is not None]
        for a, by_seed in row["by_seed"].items():
            by_seed.update(
                {s: v for s, v in zip(seeds, ev[a]["success"], strict=True) if v is not None}
            )
    rows = list(pooled.values())
    for row in rows:
        row["success"] = {a: list(values.values()) for a, values in row["by_seed"].items()}
    return sorted(rows, key=lambda r: (r["rank"], r["agent"]))


def row_metrics(row: dict, key: str) -> np.ndarray | None:
    """``key`` of metrics.npz for every agent of a (pooled) row, runs stacked on the agent
    axis; None if a run has no metrics.npz."""
    files = [d / "metrics.npz" for d in row["dirs"]]
    if not all(f.exists() for f in files):
        return None
    return np.concatenate([np.load(f)[key] for f in files], axis=0)


def _settings_text(settings: dict) -> str:
    hp = ", ".join(
        f"{k}={common.setting_text(v)}"
        for k, v in settings.items()
        if k not in ("preset", "episodes")
    )
    changed = preset_values(HParams, settings["preset"], changed_only=True)
    own = ", ".join(f"{k}={v:g}" for k, v in changed.items())
    literal = not set(SWITCHES) & (set(changed) | set(settings))
    return (
        f"preset `{settings['preset']}`"
        + (f" ({own})" if own else "")
        + f", {settings['episodes']} episodes"
        + (f", {hp}" if hp else ", the preset's hyperparameters")
        + (" (the paper's Eq. 2 as printed)" if literal else "")
    )


def _own_settings(settings: dict, shared: dict) -> str:
    """A row's settings beyond those ``shared`` by its table (all of them if none are)."""
    if not shared:
        return _settings_text(settings)
    own = {k: v for k, v in settings.items() if shared.get(k, object()) != v}
    return ", ".join(f"{k}={common.setting_text(v)}" for k, v in own.items()) or "–"


def paired_difference(better: dict, worse: dict, arena: str) -> dict | None:
    """``better`` − ``worse`` in success points, seed by seed (the same seed starts from the
    same networks and every row is scored on the same episodes), with its Student-t 95 %
    interval and a verdict: ``holds`` (interval above 0), ``reversed`` (below 0) or ``not
    resolved``. None if the rows share fewer than two seeds."""
    a, b = better["by_seed"].get(arena, {}), worse["by_seed"].get(arena, {})
    seeds = sorted(set(a) & set(b))
    if len(seeds) < 2:
        return None
    mean, half = mean_ci95([100 * (a[s] - b[s]) for s in seeds])
    verdict = "not resolved"
    if np.isfinite(half) and mean - half > 0:
        verdict = "holds"
    elif np.isfinite(half) and mean + half < 0:
        verdict = "reversed"
    return {"seeds": len(seeds), "mean": mean, "half": half, "verdict": verdict}


def comparisons(rows: list[dict]) -> list[dict]:
    """The paper's ordering and the AfP effects that these rows can test, both arenas."""
    by_agent = {r["agent"]: r for r in rows}
    out = []
    claims = (("ordering", PAPER_ORDERING), ("AfP effect", AFP_EFFECTS),
              ("over baseline", OVER_BASELINES))  # fmt: skip
    for kind, pairs in claims:
        for better, worse in pairs:
            if better in by_agent and worse in by_agent:
                diffs = {a: paired_difference(by_agent[better], by_agent[worse], a) for a in ARENAS}
                if any(diffs.values()):
                    a, b = by_agent[better]["settings"], by_agent[worse]["settings"]
                    differs = sorted(k for k in {*a, *b} if a.get(k) != b.get(k))
                    out.append(
                        {"kind": kind, "better": better, "worse": worse, "differs": differs,
                         **diffs}
                    )  # fmt: skip
    return out


def _comparison_lines(rows: list[dict]) -> list[str]:
    found = comparisons(rows)
    if not found:
        return []

    def cell(d):
        return "–" if d is None else f"{_fmt(d['mean'], d['half'])} ({d['verdict']})"

    def claim(c):
        differs = f" (differs: {', '.join(c['differs'])})" if c["differs"] else ""
        return f"{c['better']} > {c['worse']}{differs}"

    table = [
        (c["kind"], claim(c), c["training"]["seeds"] if c["training"] else "–",
         cell(c["training"]), cell(c["validation"]))
        for c in found
    ]  # fmt: skip
    return [
        "Which of the paper's claims hold here: the difference in success points, seed by "
        "seed, mean ± 95 % CI; `holds` when the interval lies above 0, `reversed` below 0. "
        "Where the two rows were trained at different settings, the claim names them: "
        "such a difference is not the agent types' alone.",
        "",
        *common.markdown_table(
            ["claim", "paper", "paired seeds", "training env", "validation env"],
            table,
            align="llrrr",
        ),
        "",
    ]


def _where_text(rows: list[dict]) -> str:
    """The device and training date of the rows: one phrase when they share them, else
    each (device, date) with the agent types trained there."""
    where: dict[tuple[str, str], list[str]] = {}
    for r in rows:
        for summary in r["summaries"]:
            agents = where.setdefault((summary["device"], summary["created"][:10]), [])
            agents += [] if r["agent"] in agents else [r["agent"]]
    if len(where) == 1:
        (device, date), _ = where.popitem()
        return f"device {device}, trained {date}"
    return "trained on " + "; ".join(
        f"{device}, {date} ({', '.join(agents)})" for (device, date), agents in where.items()
    )


def _rows_from_lines(rows: list[dict], root: Path) -> list[str]:
    moved = [r for r in rows if r.get("from")]
    return [
        f"{r['agent']}: the runs under `{r['from']}` ({_settings_text(r['settings'])}), in "
        f"place of those under `{root}`."
        for r in moved
    ] + ([""] if moved else [])


def _seeds_text(rows: list[dict]) -> str:
    """The rows' seeds: one list when they share it, else the most common list and the
    rows that have others (a pooled row with more seeds, say)."""
    sets = [tuple(sorted(r["seeds"])) for r in rows]
    common_set = max(set(sets), key=sets.count)
    others = [f"{r['agent']}: {_span(s)}" for r, s in zip(rows, sets, strict=True)
              if s != common_set]  # fmt: skip
    return _span(common_set) + (f" ({'; '.join(others)})" if others else "")


def _span(seeds: tuple[int, ...]) -> str:
    """``0-15`` for a run of consecutive seeds, else the list."""
    if len(seeds) > 2 and list(seeds) == list(range(seeds[0], seeds[-1] + 1)):
        return f"{seeds[0]}-{seeds[-1]}"
    return str(list(seeds))


def _learning_lines(rows: list[dict]) -> list[str]:
    """Training success per block of ``BLOCK`` episodes, mean over seeds (metrics.npz
    ``outcome``): when each agent type learns, which the final evaluation does not show
    (the advisor's jump start in data collection, say, and what follows it)."""
    outcomes = [(r["agent"], row_metrics(r, "outcome")) for r in rows]
    found = [(agent, outcome) for agent, outcome in outcomes if outcome is not None]
    if not found:
        return []
    n = max(outcome.shape[1] for _, outcome in found)
    starts = range(0, n, BLOCK)
    table = [
        (agent, *(f"{100 * np.mean(outcome[:, k : k + BLOCK] == GOAL):.0f}"
                  if k < outcome.shape[1] else "–" for k in starts))
        for agent, outcome in found
    ]  # fmt: skip
    return [
        f"Training success per {BLOCK} episodes (% of episodes that reached the goal, all "
        "seeds; the agent acts with its exploration and, with AfD, the advisor):",
        "",
        *common.markdown_table(
            ["agent", *(f"{k + 1}–{min(k + BLOCK, n)}" for k in starts)],
            table,
            align="l" + "r" * len(starts),
        ),
        "",
    ]


def _table_lines(rows: list[dict], root: Path) -> list[str]:
    first = rows[0]["summary"]
    distinct = {json.dumps(r["settings"], sort_keys=True) for r in rows}
    shared = {k: v for k, v in rows[0]["settings"].items()
              if all(r["settings"].get(k) == v for r in rows)}  # fmt: skip
    if len(distinct) == 1:
        settings = _settings_text(rows[0]["settings"])
    elif {"preset", "episodes"} <= set(shared):  # the column names what a row adds
        settings = _settings_text(shared) + "; a row's own settings in its settings column"
    else:
        settings, shared = "per row (see the settings column)", {}
    table = []
    for r in rows:
        cells = [_fmt(*mean_ci95([100 * v for v in r["success"][a]])) for a in ARENAS]
        speed = r["collision_speed"]
        paper = PAPER_TABLE1.get(r["agent"])
        diverged = r["diverged"]
        below = sum(v < common.ADVISOR_LEVEL for v in r["success"].get("training", []))
        table.append(
            (
                r["agent"],
                f"{len(r['seeds'])}" + (f" ({diverged} diverged)" if diverged else ""),
                *cells,
                f"{below}",
                _fmt(*mean_ci95(speed)) if speed else "–",
                f"{paper[0]:.1f} / {paper[1]:.1f}" if paper else "–",
                _own_settings(r["settings"], shared) if len(distinct) > 1 else "",
            )
        )
    header = [
        "agent",
        "seeds",
        "training env",
        "validation env",
        f"seeds below {100 * common.ADVISOR_LEVEL:g} %",
        "collision speed, eval (m/s)",
        "paper (train / val)",
        "settings",
    ]
    if len(distinct) == 1:
        header.pop()
        table = [t[:-1] for t in table]
    return [
        f"## `{root}`: {settings}",
        "",
        f"Seeds {_seeds_text(rows)}; {_where_text(rows)}; evaluation: "
        "deterministic actor, "
        f"{first['evaluation']['training']['episodes']} episodes per arena, the same episodes "
        "for every agent type. Mean ± 95 % CI over seeds (%).",
        "",
        *common.markdown_table(header, table, align="lrrrrrrl"),
        "",
        *_rows_from_lines(rows, root),
        *_comparison_lines(rows),
        *_learning_lines(rows),
    ]


def plot(tables: list[tuple[Path, list[dict]]], path: Path) -> None:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig = plt.figure(figsize=(13, 8.5), constrained_layout=True)
    grid = fig.add_gridspec(2, 2)
    ax = fig.add_subplot(grid[0, :])
    agents = sorted(
        {r["agent"] for _, rows in tables for r in rows},
        key=lambda a: (ORDER.index(a) if a in ORDER else len(ORDER), a),
    )
    groups = [(t, a) for t in range(len(tables)) for a in ARENAS]
    colors = plt.rcParams["axes.prop_cycle"].by_key()["color"]
    for g, (t, arena) in enumerate(groups):
        root, rows = tables[t]
        offset = 0.8 * (g + 0.5) / len(groups) - 0.4
        for j, r in enumerate(rows):
            label = f"{root.name}: {arena}" if j == 0 else None
            values = [100 * v for v in r["success"].get(arena, [])]
            x = agents.index(r["agent"]) + offset
            common.seeds_with_ci(ax, x, values, colors[g % len(colors)], label=label, width=0.1)
            if r["agent"] in PAPER_TABLE1:
                paper = PAPER_TABLE1[r["agent"]][ARENAS.index(arena)]
                first = g == 0 and j == 0
                ax.scatter(
                    x, paper, marker="_", s=250, color="black", label="paper" if first else None
                )
    ax.set_xticks(range(len(agents)), agents)
    ax.set_ylabel("success rate (%)")
    ax.set_ylim(-3, 103)
    ax.set_title("evaluation success per seed (dots), mean ± 95 % CI (bars), paper (black)")
    ax.grid(alpha=0.3, axis="y")
    ax.legend(fontsize=8, loc="upper left", bbox_to_anchor=(1.0, 1.0))

    curves = [fig.add_subplot(grid[1, 0]), fig.add_subplot(grid[1, 1])]
    window = 1
    for r in tables[0][1]:
        per_episode = [row_metrics(r, k) for k in ("reward_per_step", "collision_speed")]
        if per_episode[0] is None:
            continue
        episodes = np.arange(1, per_episode[0].shape[1] + 1)
        window = max(1, min(150, len(episodes) // 5))
        for c, values in zip(curves, per_episode, strict=True):
            smooth = moving_average(values.astype(np.float64), window)
            with warnings.catch_warnings():  # no collision yet in a window: NaN, not a value
                warnings.simplefilter("ignore", RuntimeWarning)
                mean, std = np.nanmean(smooth, axis=0), np.nanstd(smooth, axis=0)
            (line,) = c.plot(episodes, mean, label=r["agent"])
            c.fill_between(episodes, mean - std, mean + std, color=line.get_color(), alpha=0.15)
    curves[0].set_title(
        f"reward per step (moving average, w={window}; Fig. 8), {tables[0][0].name}"
    )
    curves[1].set_title(f"collision speed, m/s (moving average, w={window}; Fig. 9)")
    for c in curves:
        c.set_xlabel("episode")
        c.grid(alpha=0.3)
    curves[0].legend(fontsize=8)
    save_png(fig, path)


def with_rows_from(rows: list[dict], source: Path) -> list[dict]:
    """``rows`` with each agent type found under ``source`` in place of that type's row (or
    added): the first table at its settings with one type trained at other ones, e.g.
    ATD3+AfDP at policy delay 2. Each such row records ``source`` (``from``)."""
    extra = load_table(source)
    if not extra:
        sys.exit(f"--rows-from {source}: no finished runs there")
    replaced = {r["agent"] for r in extra}
    kept = [r for r in rows if r["agent"] not in replaced]
    merged = kept + [{**r, "from": source} for r in extra]
    return sorted(merged, key=lambda r: (r["rank"], r["agent"]))


def summarize(args) -> None:
    tables = []
    for root in args.runs:
        rows = load_table(root)
        if not rows:
            sys.exit(f"no finished runs under {root}")
        tables.append((root, rows))
    for source in getattr(args, "rows_from", None) or []:
        tables[0] = (tables[0][0], with_rows_from(tables[0][1], source))
    main_rows = tables[0][1]
    record = {
        "seeds": min(len(r["seeds"]) for r in main_rows),
        "agents": {
            r["agent"]: {
                **{a: [round(v, 6) for v in r["success"][a]] for a in ARENAS},
                "settings": r["settings"],
            }
            for r in main_rows
        },
    }
    atomic_write_json(args.out / "table1.json", record)
    plot(tables, args.out / "table1.png")
    lines = [
        "# Table 1 (simulation): success rate of each agent type",
        "",
        f"`table1.json` holds the first table (`{tables[0][0]}`), per seed.",
        "",
    ]
    for root, rows in tables:
        lines += _table_lines(rows, root)
    commands = list(dict.fromkeys(c for _, rows in tables for r in rows for c in r["commands"]))
    summarize_argv = ["summarize", "--runs", *args.runs, "--out", args.out]
    if getattr(args, "rows_from", None):
        summarize_argv[-2:-2] = ["--rows-from", *args.rows_from]
    lines += [
        "![per-seed success and learning curves](table1.png)",
        "",
        "Commands: "
        + ", ".join(f"`{c}`" for c in commands)
        + (", then " if commands else "")
        + f"`{common.command_line('experiments/table1.py', summarize_argv)}`.",
    ]
    common.write_markdown(args.out / "table1.md", lines, echo=True)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    sub = parser.add_subparsers(dest="command", required=True)
    t = sub.add_parser("train")
    t.add_argument("--runs", type=Path, default=Path("runs/table1"))
    t.add_argument("--preset", default="paper")
    t.add_argument("--agents", nargs="+", default=[*PAPER_AGENTS, *BASELINES])
    t.add_argument("--episodes", type=int, default=0, help="N_total (0 = the preset's)")
    t.add_argument("--seeds", type=int, default=6)
    t.add_argument("--seed", type=int, default=0)
    t.add_argument("--eval-episodes", type=int, default=100)
    t.add_argument("--export", type=Path, default=None,
                   help="copy each type's small files to EXPORT/<type>/")  # fmt: skip
    t.add_argument(
        "--hp",
        action="append",
        default=[],
        metavar="NAME=V",
        help="a hyperparameter for every agent type (repeatable), e.g. beta=1",
    )
    s = sub.add_parser("summarize")
    s.add_argument(
        "--runs",
        type=Path,
        nargs="+",
        default=[Path("runs/table1")],
        help="run folders; the first is table1.json's table",
    )
    s.add_argument(
        "--rows-from",
        type=Path,
        nargs="+",
        default=[],
        metavar="DIR",
        help="runs whose agent types replace (or join) those of the first table, "
        "e.g. one type trained at another setting",
    )
    s.add_argument("--out", type=Path, default=Path("results"))
    args = parser.parse_args()
    train(args) if args.command == "train" else summarize(args)


if __name__ == "__main__":
    main()
