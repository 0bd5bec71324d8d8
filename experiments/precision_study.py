"""Issue 17's precision evidence: does the bf16 learner learn what the fp32 one learns?

``--precision bf16`` (``AgentConfig.precision``) runs the learner's hidden layers in bf16
(fp32 parameters, Adam and accumulation). It may only be used where ≥ 16 seeds of
ATD3+AfDP and of DDPG, trained with each precision, give the same success distribution
within their intervals. This script reads those runs and writes the comparison.

Pairing: a vmapped agent's initial state and episodes depend on its seed alone, so seed s
at fp32 and seed s at bf16 start identically and differ only in the learner's arithmetic.
Each seed is scored on the same evaluation episodes under both precisions: the fp32 run's
eval seed, read from the bf16 run's ``eval.json`` or, when that run used another eval
seed, from its ``eval_seed<S>.json`` (``experiments/reevaluate.py``).

    python experiments/precision_study.py --out results

Writes ``precision_study.md``, ``.json`` and ``.png`` into ``--out``. ``STUDY`` lists the
runs (run directory, and the hyperparameters that pick its agents when the run holds a
grid).
"""

from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path

import common
import numpy as np

from advisor_jax.fileio import atomic_write_json
from advisor_jax.training.reporting import mean_ci95

ROOT = Path(__file__).resolve().parents[1]
AFP = "results/afp_collapse/run_data"
OWN = "results/precision_study/run_data"
T1 = "results/table1_stable/run_data"
STUDY: dict[str, dict[str, list[tuple[str, dict]]]] = {
    # agent (preset): precision: [(run directory, hyperparameters of its agents to take)]
    # Today's `stable` (the Q̂ clip on, ATD3's policy delay d = 4 as in the preset): the
    # fp32 runs are results/table1_stable's (Table 1's ATD3+AfDP row is d = 2, not these).
    # "cuBLAS": today's bf16 program (every GEMM on cuBLAS, twin inputs per critic; 2026-11-25).
    "ATD3+AfDP (stable, cuBLAS)": {
        "fp32": [(f"{T1}/ATD3_AfDP", {})],
        "bf16": [(f"{OWN}/atd3_afdp_stable_cublas_bf16", {})],
    },
    "DDPG (stable, cuBLAS)": {
        "fp32": [(f"{T1}/DDPG", {})],
        "bf16": [(f"{OWN}/ddpg_stable_cublas_bf16", {})],
    },
    # The bf16 program before (XLA's Triton GEMMs, twin inputs shared; 2026-11-24).
    "ATD3+AfDP (stable)": {
        "fp32": [(f"{T1}/ATD3_AfDP", {})],
        "bf16": [(f"{OWN}/atd3_afdp_stable_q_clip_bf16_seeds0-15", {})],
    },
    "DDPG (stable)": {
        "fp32": [(f"{T1}/DDPG", {})],
        "bf16": [(f"{OWN}/ddpg_stable_bf16_q_clip_seeds0-15", {})],
    },
    # `stable` before it clipped the TD target (clip_q_target = 0).
    "ATD3+AfDP (stable, no Q̂ clip)": {
        "fp32": [
            (f"{AFP}/scalefree-clip_beta0.3-1_seeds0-7", {"beta": 1.0}),
            (f"{AFP}/clip-beta1_literal-vs-scalefree_seeds8-15", {"beta_normalize": 1.0}),
        ],
        "bf16": [(f"{OWN}/atd3_afdp_stable_bf16_seeds0-15", {})],
    },
    "DDPG (stable, no Q̂ clip)": {
        "fp32": [(f"{OWN}/ddpg_stable_fp32_seeds0-15", {})],
        "bf16": [(f"{OWN}/ddpg_stable_bf16_seeds0-15", {})],
    },
}
ARENAS = ("training", "validation")


def run_eval_seed(summary: dict) -> int:
    """The run's evaluation seed (runs before ``--eval-seed`` used the first seed)."""
    return int(summary.get("eval_seed", summary["agents"][0]["seed"]))


def load_agents(run_dir: Path, select: dict, eval_seeds: dict[int, int] | None = None) -> dict:
    """``{seed: {"eval_seed", arena: success}}`` of the run's agents whose hyperparameters
    match ``select``. With ``eval_seeds`` ({seed: eval seed}), each seed's success is read
    from the evaluation on that eval seed (eval.json, or eval_seed<S>.json); otherwise
    from eval.json."""
    summary = json.loads((run_dir / "run.json").read_text())
    own = run_eval_seed(summary)
    files: dict[int, dict] = {}

    def evaluation(eval_seed: int) -> dict:
        if eval_seed not in files:
            name = "eval.json" if eval_seed == own else f"eval_seed{eval_seed}.json"
            path = run_dir / name
            if not path.is_file():
                raise SystemExit(
                    f"{run_dir}: no evaluation on eval seed {eval_seed} ({name}); run "
                    f"experiments/reevaluate.py {run_dir} --eval-seed {eval_seed}"
                )
            files[eval_seed] = json.loads(path.read_text())
        return files[eval_seed]

    out = {}
    for i, agent in enumerate(summary["agents"]):
        if any(abs(agent.get(k, np.nan) - v) > 1e-12 for k, v in select.items()):
            continue
        seed = int(agent["seed"])
        if eval_seeds is not None and seed not in eval_seeds:
            continue
        eval_seed = own if eval_seeds is None else eval_seeds[seed]
        ev = evaluation(eval_seed)
        out[seed] = {"eval_seed": eval_seed, **{a: ev[a]["success"][i] for a in ARENAS}}
    return out


def compare(study: dict, root: Path) -> list[dict]:
    """One row per agent type: per-seed success of each precision, paired on seed and
    evaluation episodes, and the bf16 - fp32 differences."""
    rows = []
    for agent, runs in study.items():
        fp32: dict[int, dict] = {}
        for run, select in runs["fp32"]:
            fp32.update(load_agents(root / run, select))
        eval_seeds = {s: v["eval_seed"] for s, v in fp32.items()}
        bf16: dict[int, dict] = {}
        for run, select in runs["bf16"]:
            bf16.update(load_agents(root / run, select, eval_seeds))
        seeds = sorted(set(fp32) & set(bf16))
        row = {"agent": agent, "seeds": seeds, "runs": runs}
        for arena in ARENAS:
            a = np.array([fp32[s][arena] for s in seeds], float)
            b = np.array([bf16[s][arena] for s in seeds], float)
            row[arena] = {
                "fp32": a.tolist(),
                "bf16": b.tolist(),
                "fp32_mean_ci": mean_ci95(a),
                "bf16_mean_ci": mean_ci95(b),
                "difference_mean_ci": mean_ci95(b - a),
                "collapsed": {"fp32": int((a < common.ADVISOR_LEVEL).sum()),
                              "bf16": int((b < common.ADVISOR_LEVEL).sum())},
            }  # fmt: skip
        rows.append(row)
    return rows


def verdict(cell: dict) -> str:
    """Whether the two precisions agree: each mean inside the other's 95 % interval and
    the paired difference's interval holding 0."""
    (ma, ha), (mb, hb) = cell["fp32_mean_ci"], cell["bf16_mean_ci"]
    md, hd = cell["difference_mean_ci"]
    same = abs(mb - ma) <= min(ha, hb) and abs(md) <= hd
    return "same within the intervals" if same else "differs"


def pct(mean_ci) -> str:
    m, h = mean_ci
    return f"{100 * m:.1f} ± {100 * h:.1f}"


def plot(path: Path, rows: list[dict]) -> None:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    from advisor_jax.training.plots import save_png

    per_line = 2 * len(ARENAS)  # two agent rows per line of panels
    lines = -(-len(rows) * len(ARENAS) // per_line)
    fig, axes = plt.subplots(lines, per_line, figsize=(3.2 * per_line, 3.6 * lines),
                             sharey=True, squeeze=False)  # fmt: skip
    for ax in axes.flat[len(rows) * len(ARENAS) :]:
        ax.set_visible(False)
    for j, (row, arena) in enumerate((r, a) for r in rows for a in ARENAS):
        ax = axes[j // per_line, j % per_line]
        a, b = 100 * np.array(row[arena]["fp32"]), 100 * np.array(row[arena]["bf16"])
        for x, y in zip(a, b, strict=True):
            ax.plot([0, 1], [x, y], color="0.75", lw=0.8)
        ax.scatter(np.zeros_like(a), a, s=14, color="tab:blue", zorder=3)
        ax.scatter(np.ones_like(b), b, s=14, color="tab:orange", zorder=3)
        for k, key in enumerate(("fp32_mean_ci", "bf16_mean_ci")):
            m, h = row[arena][key]
            ax.errorbar(k + 0.15, 100 * m, yerr=100 * h, fmt="s", color="k", capsize=3)
        ax.axhline(100 * common.ADVISOR_LEVEL, color="tab:red", lw=0.8, ls=":")
        ax.set_xticks([0, 1], ["fp32", "bf16"])
        ax.set_xlim(-0.4, 1.5)
        ax.set_title(f"{row['agent']}\n{arena}", fontsize=9)
    for ax in axes[:, 0]:
        ax.set_ylabel("evaluation success % (per seed, paired)")
    fig.tight_layout()
    save_png(fig, path)
    plt.close(fig)


def main() -> None:
    parser = argparse.ArgumentParser(
        description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter
    )
    parser.add_argument("--root", type=Path, default=ROOT, help="where STUDY's paths start")
    parser.add_argument("--out", type=Path, default=Path("results"))
    args = parser.parse_args()
    rows = compare(STUDY, args.root)
    train_seconds = {
        run: json.loads((args.root / run / "run.json").read_text()).get("train_seconds")
        for r in rows for runs in r["runs"].values() for run, _ in runs
    }  # fmt: skip
    atomic_write_json(
        args.out / "precision_study.json", {"rows": rows, "train_seconds": train_seconds}
    )
    table = []
    for row in rows:
        for arena in ARENAS:
            cell = row[arena]
            table.append((row["agent"], arena, len(row["seeds"]), pct(cell["fp32_mean_ci"]),
                          pct(cell["bf16_mean_ci"]), pct(cell["difference_mean_ci"]),
                          f"{cell['collapsed']['fp32']} / {cell['collapsed']['bf16']}",
                          verdict(cell)))  # fmt: skip
    commands = []
    for row in rows:
        for runs in row["runs"].values():
            for run, select in runs:
                info = json.loads((args.root / run / "command.json").read_text())
                picked = f" (agents with {select})" if select else ""
                commands.append(
                    f"- `{run}`{picked}: `{info['command']}`, {info['device']}, "
                    f"{info['created'][:10]}, training {train_seconds[run]:.0f} s"
                    + (" (side by side with another run on the GPU)"
                       if "side by side" in info.get("machine", "") else "")
                )  # fmt: skip
    lines = [
        "# fp32 vs bf16 learner: the same learning? (issue 17)",
        "",
        "Evaluation success in %, mean ± half-width of the Student-t 95 % interval over "
        "seeds; each seed trained once per precision (same initial networks and episodes) "
        "and scored on the same 50 evaluation episodes per arena under both. Difference: "
        "bf16 − fp32, paired by seed. Collapsed: seeds below the advisor's 50 %.",
        "",
        *common.markdown_table(
            (
                "agent",
                "arena",
                "seeds",
                "fp32 %",
                "bf16 %",
                "bf16 − fp32 (points)",
                "collapsed fp32 / bf16",
                "verdict",
            ),
            table,
            align="llr",
        ),  # fmt: skip
        "",
        "Verdict: *same within the intervals* when each precision's mean lies inside the "
        "other's 95 % interval and the paired difference's interval holds 0.",
        "",
        "![per-seed success, fp32 and bf16, paired](precision_study.png)",
        "",
        "Runs (500 episodes). `stable` rows: today's preset, which clips the TD target, "
        "with ATD3's policy delay at the preset's d = 4 (the fp32 runs are those of "
        "`results/table1_stable/run_data`, on an H200, not Table 1's d = 2 ATD3+AfDP row; "
        "the bf16 runs on an H100). `cuBLAS` rows: today's bf16 program, every GEMM on "
        "cuBLAS (`training/program.py`) and the twin critics' inputs per critic; "
        "the other bf16 rows ran XLA's Triton GEMMs with shared twin inputs. "
        "`no Q̂ clip` rows: `stable` as it was before, at "
        "`clip_q_target=0` (all on an H100; the fp32 ATD3+AfDP runs are issue 16's). "
        "A seed's initial networks and episodes do not depend on the GPU; the "
        "arithmetic's last bits do.",
        "",
        *commands,
        "",
        f"Command: `{common.command_line('experiments/precision_study.py', sys.argv[1:])}`",
    ]
    common.write_markdown(args.out / "precision_study.md", lines)
    plot(args.out / "precision_study.png", rows)


if __name__ == "__main__":
    main()
