"""How much does a population's success depend on which evaluation episodes it is scored on?

Every agent of a run is scored on the same episodes (``--eval-seed``, default the first
seed: ``population.eval_key``), so that comparisons within a study are paired (R30). The
interval printed with a success rate is over seeds *on those episodes*: it leaves out how the
population mean would move on another set of as many episodes. This measures that term for
a finished run: its agents scored on SETS other sets of EPISODES episodes each (eval seeds
FIRST, FIRST+1, ...) and on one large set (REFERENCE_EPISODES episodes of eval seed
REFERENCE_SEED), the best estimate here of the mean over all episodes; per arena, the spread
of the sets' population means, how often a set's interval holds the large set's mean (the
seeds' t interval: 95 % only if the episodes did not matter; the interval for new seeds and
episodes, ``stats.seeds_and_episodes_interval``: 95 % if it is right), and where the run's
own evaluation lies.

    python experiments/eval_set_variance.py RUN --out OUT [--episodes 50 --sets 20
        --reference-episodes 2000]

Writes OUT/eval_set_variance.{json,md}. Each arena's evaluator is compiled once (two sizes).
"""

from __future__ import annotations

import argparse
import math
import sys
from pathlib import Path

import numpy as np
from rich.progress import track

from advisor_jax.bench import writing
from advisor_jax.evaluation.evaluate import (
    evaluate_population,
    population_evaluator,
    success_table,
)
from advisor_jax.fileio import atomic_write_json
from advisor_jax.stats import seeds_and_episodes_interval, t_interval
from advisor_jax.training.population import eval_key
from advisor_jax.training.run_directory import load_params, load_run


def population_means(scores: dict) -> dict[str, tuple[float, float, float]]:
    """Per arena of ``evaluate_population``'s output: (mean success over the agents that did
    not diverge, the half-width of its 95 % t interval over them, and that of the interval
    for new seeds and episodes, ``stats.seeds_and_episodes_interval``; NaN without
    outcomes), in points."""
    out = {}
    for arena, rates in scores.items():
        success = [s for s in rates["success"] if s is not None]
        table = success_table(rates)
        both = math.nan if table is None else seeds_and_episodes_interval(table).half
        out[arena] = (100 * float(np.mean(success)), 100 * t_interval(success).half, 100 * both)
    return out


def summarise(sets: list[dict], reference: dict, own: dict | None) -> dict:
    """Per arena: the sets' population means against the reference mean."""
    rows = {}
    for arena, (truth, *_) in reference.items():
        means = np.array([s[arena][0] for s in sets])
        widths = np.array([s[arena][1] for s in sets])
        both = np.array([s[arena][2] for s in sets])
        rows[arena] = dict(
            reference_mean=round(truth, 2),
            set_means=[round(m, 2) for m in means],
            set_sd=round(float(means.std(ddof=1)), 2),
            set_range=[round(float(means.min()), 2), round(float(means.max()), 2)],
            mean_half_width=round(float(widths.mean()), 2),
            coverage=round(float(np.mean(np.abs(means - truth) <= widths)), 3),
            mean_half_width_seeds_and_episodes=round(float(both.mean()), 2),
            coverage_seeds_and_episodes=round(float(np.mean(np.abs(means - truth) <= both)), 3),
        )
        if own is not None and arena in own:
            rows[arena]["own_mean"] = round(own[arena][0], 2)
            rows[arena]["own_offset"] = round(own[arena][0] - truth, 2)
    return rows


def main(argv=None) -> dict:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("run", type=Path, help="a finished run directory")
    parser.add_argument("--out", type=Path, required=True)
    parser.add_argument("--episodes", type=int, default=50, help="episodes per set")
    parser.add_argument("--sets", type=int, default=20, help="sets of --episodes episodes")
    parser.add_argument("--first", type=int, default=1, help="eval seed of the first set")
    parser.add_argument("--reference-episodes", type=int, default=2000)
    parser.add_argument("--reference-seed", type=int, default=1000)
    args = parser.parse_args(argv)
    if args.sets < 2:
        parser.error(f"--sets {args.sets}: at least 2 sets give a spread")
    if args.reference_seed in range(args.first, args.first + args.sets):
        parser.error(f"--reference-seed {args.reference_seed} is one of the sets' eval seeds")
    cfg, summary = load_run(args.run)
    if summary["status"] != "finished":
        parser.error(f"{args.run} has status {summary['status']!r}: no final parameters")
    arenas = tuple(summary.get("evaluation") or ("training", "validation"))
    actor = load_params(args.run, summary)["actor"]
    diverged = np.zeros(len(summary["agents"]), bool)
    diverged[summary.get("diverged", [])] = True

    def evaluators(episodes: int) -> dict:
        hidden, steps = cfg.agent.actor_hidden, cfg.max_episode_steps
        return {a: population_evaluator(a, episodes, hidden, steps, cfg.motion) for a in arenas}

    def score(evaluator: dict, seed: int) -> dict:
        return population_means(evaluate_population(evaluator, actor, eval_key(seed), diverged))

    per_set = evaluators(args.episodes)
    seeds = range(args.first, args.first + args.sets)
    sets = [score(per_set, s) for s in track(seeds, description="evaluation sets")]
    reference = score(evaluators(args.reference_episodes), args.reference_seed)
    own = population_means(summary["evaluation"]) if summary.get("evaluation") else None
    record = dict(
        run=str(args.run), agents=len(summary["agents"]), agent=summary["agent"],
        own_eval_seed=summary.get("eval_seed"),
        own_episodes=(summary.get("evaluation") or {}).get(arenas[0], {}).get("episodes"),
        episodes=args.episodes, set_eval_seeds=list(seeds),
        reference_episodes=args.reference_episodes, reference_seed=args.reference_seed,
        arenas=summarise(sets, reference, own),
    )  # fmt: skip
    args.out.mkdir(parents=True, exist_ok=True)
    atomic_write_json(args.out / "eval_set_variance.json", record)
    (args.out / "eval_set_variance.md").write_text(page(record, argv))
    print(page(record, argv))
    return record


def page(record: dict, argv) -> str:
    """The record as a markdown page with its command."""
    rows = [
        (arena, r["reference_mean"], r["set_sd"], f"{r['set_range'][0]}–{r['set_range'][1]}",
         f"{r['mean_half_width']} / {r['mean_half_width_seeds_and_episodes']}",
         f"{100 * r['coverage']:.0f} % / {100 * r['coverage_seeds_and_episodes']:.0f} %",
         "–" if "own_offset" not in r else f"{r['own_mean']} ({r['own_offset']:+.1f})")
        for arena, r in record["arenas"].items()
    ]  # fmt: skip
    table = "\n".join(writing.markdown_table(
        ("arena", f"mean on {record['reference_episodes']} episodes",
         f"sd of the sets' means ({record['episodes']} episodes each)", "their range",
         "half-width (mean): seeds / seeds and episodes",
         "sets whose interval holds the large set's mean: seeds / seeds and episodes",
         f"the run's own evaluation ({record['own_episodes']} episodes, eval seed "
         f"{record['own_eval_seed']})"),
        rows, align="l",
    ))  # fmt: skip
    given = sys.argv[1:] if argv is None else argv
    return (
        f"# {record['agent']}, {record['agents']} agents: success on other evaluation "
        f"episodes\n\n{len(record['set_eval_seeds'])} sets of {record['episodes']} episodes "
        f"(eval seeds {record['set_eval_seeds'][0]}–{record['set_eval_seeds'][-1]}) and "
        f"{record['reference_episodes']} episodes of eval seed {record['reference_seed']}; "
        "success in points, mean over the agents.\n\n"
        f"{table}\n\nCommand: `{writing.command_line('experiments/eval_set_variance.py', given)}`\n"
    )


if __name__ == "__main__":
    main()
