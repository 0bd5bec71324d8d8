"""The same agent types trained at two settings, compared seed by seed.

    python experiments/compare_settings.py results/table1_stable/run_data \\
        results/table1_stable/run_data_no_qclip --name q_target_clip --out results

Both arguments are directories of finished runs, one agent type per run, as
``table1.py summarize`` reads them (``advisor-jax train`` writes a run; the device tool's
runs keep run.json, eval.json, metrics.npz and command.json). Agent types found under both
are paired **by seed**: the same seed starts from the same networks and replay, and both
sides are scored on the same evaluation episodes, so the seed-by-seed difference removes
most of the seed-to-seed spread (``table1.paired_difference``).

Per agent type it reports, for the treatment (first directory) and the control (second):
evaluation success per arena (mean ± Student-t 95 % interval), the paired difference with
its verdict, the worst seed, the seeds that ended below the advisor's own success
(``--advisor-level``, ``common.ADVISOR_LEVEL``), and from the per-agent training logs
(``afp_collapse.analyse_run``) how many seeds' batch-mean Q left the arena's return bound
(``envs.reward.return_bounds``) and the largest batch-mean Q. Writes ``<name>.md``,
``.json`` and ``.png`` (each seed's success at both settings, joined by a line) into
``--out``.
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

import afp_collapse
import common
import table1

from advisor_jax.fileio import atomic_write_json
from advisor_jax.training.plots import save_png
from advisor_jax.training.reporting import mean_ci95


def setting_difference(treatment: dict, control: dict, agent: str) -> str:
    """The settings in which two rows of ``agent`` differ, e.g. ``clip_q_target=1 vs 0``;
    unset ones are the preset's (``common.preset_differences``)."""
    keys = sorted(k for k in {*treatment, *control} if treatment.get(k) != control.get(k))
    if not keys:
        return "the same settings"

    def value(settings, k):
        if k in settings:
            return common.setting_text(settings[k])
        default = common.preset_setting(settings["preset"], agent, k)
        return f"{common.setting_text(default)} (the preset's)"

    return ", ".join(f"{k}={value(treatment, k)} vs {value(control, k)}" for k in keys)


def side_stats(row: dict, analysed: list[dict], level: float) -> dict:
    """One agent type at one setting: success per arena, worst seed, seeds below ``level``,
    and the critic's batch-mean Q against the return bound over training."""
    training = row["success"].get("training", [])
    max_q = [a["max_q"] for a in analysed if a["max_q"] is not None]
    return dict(
        seeds=len(training),
        **{
            arena: dict(zip(("mean", "half"), mean_ci95([100 * v for v in values]), strict=True))
            for arena, values in row["success"].items()
        },
        worst=100 * min(training) if training else None,
        below_advisor=sum(v < level for v in training),
        q_over_bound=sum(a["q_over_bound_at"] is not None for a in analysed),
        max_q=max(max_q) if max_q else None,
        q_bound=analysed[0]["q_bound"] if analysed else None,
        device=row["summary"]["device"],
        created=row["summary"]["created"][:10],
        commands=row["commands"],
    )


def analysed(row: dict, thresholds) -> list[dict]:
    """``afp_collapse.analyse_run`` of every run of a (pooled) Table 1 row."""
    return [a for d in row["dirs"] for a in afp_collapse.analyse_run(d, thresholds)]


def compare(treatment_root: Path, control_root: Path, level: float) -> list[dict]:
    """One entry per agent type found under both roots, in Table 1's order."""
    thresholds = argparse.Namespace(
        advisor_level=level, saturated=afp_collapse.SATURATED, blowup=afp_collapse.BLOWUP
    )
    control = {r["agent"]: r for r in table1.load_table(control_root)}
    out = []
    for t in table1.load_table(treatment_root):
        c = control.get(t["agent"])
        if c is None:
            continue
        sides = {
            name: side_stats(row, analysed(row, thresholds), level)
            for name, row in (("treatment", t), ("control", c))
        }
        out.append(
            dict(
                agent=t["agent"],
                difference=setting_difference(t["settings"], c["settings"], t["agent"]),
                **sides,
                paired={a: table1.paired_difference(t, c, a) for a in table1.ARENAS},
                by_seed={"treatment": t["by_seed"], "control": c["by_seed"]},
            )
        )
    return out


def plot(rows: list[dict], path: Path, labels: tuple[str, str]) -> None:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, axes = plt.subplots(1, 2, figsize=(12, 4.8), sharey=True, constrained_layout=True)
    for ax, arena in zip(axes, table1.ARENAS, strict=True):
        for i, r in enumerate(rows):
            treated, control = r["by_seed"]["treatment"][arena], r["by_seed"]["control"][arena]
            seeds = sorted(set(treated) & set(control))
            x0, x1 = i - 0.18, i + 0.18
            for s in seeds:
                worse = treated[s] < control[s]
                ax.plot([x0, x1], [100 * control[s], 100 * treated[s]], lw=0.8, alpha=0.5,
                        color="tab:red" if worse else "tab:gray")  # fmt: skip
            for x, side, color in ((x0, control, "tab:orange"), (x1, treated, "tab:blue")):
                values = [100 * side[s] for s in seeds]
                mean, half = mean_ci95(values)
                ax.errorbar(x, mean, yerr=half, fmt="o", ms=6, capsize=4, color=color,
                            markeredgecolor="black")  # fmt: skip
        ax.axhline(100 * common.ADVISOR_LEVEL, color="black", ls=":", lw=1)
        ax.set_xticks(range(len(rows)), [r["agent"] for r in rows], rotation=20)
        ax.set_title(f"{arena} arena: {labels[1]} (orange) → {labels[0]} (blue)", fontsize=10)
        ax.grid(alpha=0.3, axis="y")
    axes[0].set_ylabel("evaluation success per seed (%)")
    save_png(fig, path)


def _pair(treatment: float | None, control: float | None, fmt: str) -> str:
    return " / ".join("–" if v is None else format(v, fmt) for v in (treatment, control))


def _cell(d: dict | None) -> str:
    if d is None:
        return "–"
    return f"{d['mean']:.1f} ± {d['half']:.1f} ({d['verdict']})"


def markdown(rows: list[dict], args, where: dict) -> list[str]:
    def side(s):
        return (
            f"{s['training']['mean']:.1f} ± {s['training']['half']:.1f} / "
            f"{s['validation']['mean']:.1f} ± {s['validation']['half']:.1f}"
        )

    differences = sorted({r["difference"] for r in rows})
    table = [
        (
            r["agent"],
            r["paired"]["training"]["seeds"] if r["paired"]["training"] else 0,
            side(r["treatment"]),
            side(r["control"]),
            _cell(r["paired"]["training"]),
            _cell(r["paired"]["validation"]),
            *(
                _pair(r["treatment"][key], r["control"][key], fmt)
                for key, fmt in (
                    ("worst", ".0f"),
                    ("below_advisor", "d"),
                    ("q_over_bound", "d"),
                    ("max_q", ".1f"),
                )
            ),  # fmt: skip
        )
        for r in rows
    ]
    devices = sorted(
        {f"{r[s]['device']} ({r[s]['created']})" for r in rows for s in ("treatment", "control")}
    )
    commands = [c for s in ("treatment", "control") for r in rows for c in r[s]["commands"]]
    level = 100 * args.advisor_level
    bound = rows[0]["treatment"]["q_bound"]
    return [
        f"# {args.title or args.name}: {args.treatment} against {args.control}",
        "",
        f"Settings that differ: {'; '.join(differences)}. Seeds paired by seed (same "
        "initial networks, same evaluation episodes). Evaluation success, training / "
        "validation arena, mean ± 95 % CI over seeds (%); the paired difference is "
        "treatment − control, seed by seed; `holds` when its interval lies above 0.",
        "",
        *common.markdown_table(
            (
                "agent",
                "paired seeds",
                "treatment",
                "control",
                "difference, training",
                "difference, validation",
                "worst seed (treatment / control)",
                f"seeds below {level:g} %",
                f"seeds with Q above {bound:.1f}",
                "largest batch-mean Q",
            ),
            table,
            align="lrrrrrrrrr",
        ),
        "",
        f"Q above {bound:.1f}: the batch-mean Q(S, A) of a seed's critic passed the largest "
        "discounted return any policy can collect in the arena (`envs.reward.return_bounds`) "
        "at some point of training, i.e. it overestimated.",
        "",
        f"![each seed at both settings]({args.name}.png)",
        "",
        f"Trained on: {'; '.join(devices)}. Analysed {where['date']}.",
        "",
        "Commands: " + ", ".join(f"`{c}`" for c in dict.fromkeys(commands)) + ", then "
        f"`{common.command_line('experiments/compare_settings.py', sys.argv[1:])}`.",
    ]


def main() -> None:
    parser = argparse.ArgumentParser(
        description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter
    )
    parser.add_argument("treatment", type=Path, help="runs at the setting under test")
    parser.add_argument("control", type=Path, help="the same agent types at the other setting")
    parser.add_argument("--name", default="compare_settings", help="report file name")
    parser.add_argument("--title", default=None, help="report title (default: --name)")
    parser.add_argument("--out", type=Path, default=Path("results"))
    parser.add_argument("--advisor-level", type=float, default=common.ADVISOR_LEVEL)
    parser.add_argument(
        "--labels",
        nargs=2,
        default=("treatment", "control"),
        metavar=("TREATMENT", "CONTROL"),
        help="names of the two settings in the figure",
    )
    args = parser.parse_args()
    for root in (args.treatment, args.control):
        if not root.is_dir():
            parser.error(f"{root} is not a directory of runs")
    rows = compare(args.treatment, args.control, args.advisor_level)
    if not rows:
        sys.exit(f"no agent type finished under both {args.treatment} and {args.control}")
    where = common.provenance(with_jax=False)
    args.out.mkdir(parents=True, exist_ok=True)
    plot(rows, args.out / f"{args.name}.png", tuple(args.labels))
    atomic_write_json(
        args.out / f"{args.name}.json",
        dict(analysed=where, treatment=str(args.treatment), control=str(args.control),
             advisor_level=args.advisor_level, agents=rows),
    )  # fmt: skip
    common.write_markdown(args.out / f"{args.name}.md", markdown(rows, args, where), echo=True)


if __name__ == "__main__":
    main()
