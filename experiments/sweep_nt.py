"""Paper Fig. 6: success of ADDPG+AfD agents against the advisor's terminal episode N_T.

The whole sweep (every N_T × every seed) is ONE vmapped program and one compile: N_T is a
scalar hyperparameter (``HParams.advisor_episodes``).

    python experiments/sweep_nt.py --episodes 200 --seeds 4 --nt 0 50 100 150 200 \\
        --runs runs/sweep_nt --out results

Writes ``results/sweep_nt.md`` and ``results/sweep_nt.png`` (mean ± 95 % CI over seeds).
"""

from __future__ import annotations

import argparse
import dataclasses
import json
from pathlib import Path

import common
import numpy as np

from advisor_jax.agent.config import preset
from advisor_jax.training.plots import save_png
from advisor_jax.training.reporting import group_agents, mean_ci95


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--preset", default="paper")
    parser.add_argument("--agent", default="ADDPG+AfD")
    parser.add_argument("--episodes", type=int, default=0, help="N_total (0 = the preset's)")
    parser.add_argument("--nt", type=float, nargs="+", default=[0, 100, 200, 300, 400, 500])
    parser.add_argument("--seeds", type=int, default=4)
    parser.add_argument("--eval-episodes", type=int, default=100)
    parser.add_argument("--runs", type=Path, default=Path("runs/sweep_nt"))
    parser.add_argument("--out", type=Path, default=Path("results"))
    parser.add_argument("--summarize-only", action="store_true")
    args = parser.parse_args()

    if not args.summarize_only:
        from advisor_jax.training.host_loop import run_training

        cfg, hp = preset(args.preset, args.agent)
        cfg = dataclasses.replace(cfg, episodes=args.episodes or cfg.episodes)
        run_training(
            cfg,
            hp,
            {"advisor_episodes": args.nt},
            list(range(args.seeds)),
            args.runs,
            eval_episodes=args.eval_episodes,
            checkpoint_every=0,
            progress=False,
            meta={"preset": args.preset},
        )
    summary = json.loads((args.runs / "run.json").read_text())
    grid = summary["grid"]
    ev = summary["evaluation"]
    rows = []
    for (n_t,), members in group_agents(summary["agents"], grid).items():
        cells = {"N_T": n_t}
        for arena in ev:
            values = [100 * ev[arena]["success"][m] for m in members]
            cells[arena] = mean_ci95([v for v in values if v is not None])
        rows.append(cells)

    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, ax = plt.subplots(figsize=(6, 4), constrained_layout=True)
    n_total = summary["config"]["episodes"]
    for arena in ev:
        x = [100 * r["N_T"] / n_total for r in rows]
        mean = np.array([r[arena][0] for r in rows])
        half = np.nan_to_num(np.array([r[arena][1] for r in rows]))
        ax.errorbar(x, mean, yerr=half, marker="o", capsize=3, label=f"{arena} env")
    ax.set_xlabel("advisor contribution N_T / N_total (%)")
    ax.set_ylabel("success rate (%)")
    ax.set_title(f"{summary['agent']}, {n_total} episodes (Fig. 6)")
    ax.grid(alpha=0.3)
    ax.legend()
    save_png(fig, args.out / "sweep_nt.png")

    arenas = list(ev)
    seeds = len(summary["agents"]) // len(rows)
    argv = ["--preset", args.preset, "--agent", args.agent, "--episodes", n_total]
    argv += ["--seeds", seeds, "--nt", *(f"{r['N_T']:g}" for r in rows)]
    argv += ["--runs", args.runs, "--out", args.out]
    lines = [
        "# Fig. 6: success against the advisor's terminal episode N_T",
        "",
        f"{summary['agent']}, {n_total} training episodes in `{summary['config']['arena']}`, "
        f"{len(summary['agents'])} agents ({len(rows)} values of N_T × "
        f"{seeds} seeds) in one vmapped program; "
        f"{summary['train_seconds']:.0f} s of training on {summary['device']} "
        f"({summary['created'][:10]}). Evaluation: {ev[arenas[0]]['episodes']} episodes per "
        "arena, the same for every agent. Mean ± 95 % CI over seeds.",
        "",
        *common.markdown_table(
            ("N_T", "N_T / N_total", *(f"{a} env success (%)" for a in arenas)),
            [(f"{r['N_T']:g}", f"{100 * r['N_T'] / n_total:.0f} %",
              *(f"{r[a][0]:.1f} ± {r[a][1]:.1f}" for a in arenas)) for r in rows],
            align="r",
        ),
        "",
        "![success vs N_T](sweep_nt.png)",
        "",
        f"Command: `{common.command_line('experiments/sweep_nt.py', argv)}`",
    ]  # fmt: skip
    common.write_markdown(args.out / "sweep_nt.md", lines, echo=True)


if __name__ == "__main__":
    main()
