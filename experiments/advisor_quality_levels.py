"""The advisors' own success under quality knobs (docs/advisors.md): which settings give an
advisor of ~20, 35, 50, 65, 80 % success, for the advisor-quality study.

Each advisor is evaluated alone, through the interface the trainer uses
(``evaluation.evaluate.advisor_evaluator``), on the episodes of the study's evaluation seed
(``eval_key(--eval-seed)``, the episodes every agent of the study is scored on), all knob
settings of one advisor and arena in one vmapped program::

    python experiments/advisor_quality_levels.py \\
        --advisors rule experiments/paper/advisors/atd3_quick_300ep \\
        --settings "" advisor_random=0.2 "advisor_random=0.4,advisor_noise=0.2" \\
        --episodes 500 --out results/advisor_quality_advisors

writes ``--out``.json (one row per advisor, setting and arena: success, collision and timeout
rates, mean collision speed; provenance, command) and ``--out``.md.
"""

from __future__ import annotations

import dataclasses
import sys

import jax
import jax.numpy as jnp
import tyro

import envs
from advisor_jax.agent.advisor_quality import AdvisorQuality
from advisor_jax.agent.settings import flat_items, replace_flat, validate
from advisor_jax.bench import measure, writing
from advisor_jax.evaluation.evaluate import advisor_evaluator, summary
from advisor_jax.fileio import atomic_write_json
from advisor_jax.training.advisor_source import resolve_advisor
from advisor_jax.training.population import eval_key, parse_assignments


@dataclasses.dataclass(frozen=True)
class Args:
    advisors: tuple[str, ...] = ("rule",)
    """Advisor specs (docs/advisors.md): rule, MODULE:FUNCTION, RUN[:AGENT], export dirs."""
    settings: tuple[str, ...] = ("",)
    """Knob settings, each "name=value,name=value" ("" = the advisor as it is)."""
    arenas: tuple[str, ...] = ("training", "validation")
    episodes: int = 500
    """Episodes per advisor, setting and arena (the paper measures its advisor on 500)."""
    eval_seed: int = 0
    """The study's eval_seed: the advisors are scored on its agents' evaluation episodes."""
    out: str = "results/advisor_quality_advisors"
    """Output path without extension (.json and .md)."""
    notes: tuple[str, ...] = ()
    """Lines for the report (where an advisor came from)."""


def parse_setting(text: str) -> AdvisorQuality:
    """'advisor_random=0.2,advisor_noise=0.1' -> AdvisorQuality (checked)."""
    items = [item for item in text.split(",") if item.strip()]
    values = parse_assignments(items, "--settings")
    quality = replace_flat(AdvisorQuality(), **{k: v[0] for k, v in values.items()})
    validate(quality)
    return quality


def label(quality: AdvisorQuality) -> str:
    """The knobs that differ from their defaults ("as it is" for none)."""
    default = flat_items(AdvisorQuality())
    changed = [f"{k}={float(v):g}" for k, v in flat_items(quality).items() if v != default[k]]
    return ", ".join(changed) or "as it is"


def measure_advisor(spec: str, qualities, arena: str, episodes: int, key) -> list[dict]:
    env = envs.make_env(arena)
    advisor = resolve_advisor(spec, env)
    stacked = jax.tree.map(lambda *v: jnp.asarray(v, jnp.float32), *qualities)
    metrics, seconds = measure.run_timed(
        lambda: advisor_evaluator(env, advisor, episodes)(stacked, key)
    )
    rows = []
    for i, quality in enumerate(qualities):
        one = jax.tree.map(lambda x, i=i: x[i], metrics)
        rows.append(
            {
                "advisor": spec,
                "advisor_record": advisor.record(),
                "knobs": {k: float(v) for k, v in flat_items(quality).items()},
                "setting": label(quality),
                "arena": arena,
                **summary(one),
            }
        )
    print(f"{spec} in {arena}: {len(qualities)} settings in {seconds:.0f} s", flush=True)
    return rows


def main(args: Args) -> dict:
    qualities = [parse_setting(s) for s in args.settings]
    key = eval_key(args.eval_seed)
    rows = [
        row
        for spec in args.advisors
        for arena in args.arenas
        for row in measure_advisor(spec, qualities, arena, args.episodes, key)
    ]
    where = measure.provenance()
    result = {
        **where,
        "command": writing.command_line("experiments/advisor_quality_levels.py", sys.argv[1:]),
        "eval_seed": args.eval_seed,
        "episodes": args.episodes,
        "notes": list(args.notes),
        "rows": rows,
    }
    atomic_write_json(f"{args.out}.json", result)
    writing.write_markdown(f"{args.out}.md", markdown(result, args), echo=True)
    return result


def markdown(result: dict, args: Args) -> list[str]:
    by_setting: dict[tuple, dict] = {}
    for row in result["rows"]:
        cell = by_setting.setdefault((row["advisor"], row["setting"]), {})
        cell[row["arena"]] = row
    header = ["advisor", "knobs", *(f"success {a} (%)" for a in args.arenas),
              *(f"collision {a} (%)" for a in args.arenas)]  # fmt: skip
    table = [
        [f"`{advisor}`", setting]
        + [f"{100 * cells[a]['success_rate']:.1f}" for a in args.arenas]
        + [f"{100 * cells[a]['collision_rate']:.1f}" for a in args.arenas]
        for (advisor, setting), cells in by_setting.items()
    ]
    return [
        "# The advisors' own success under quality knobs",
        "",
        f"- command: `{result['command']}`",
        f"- machine: {result['cpu']}, {result['cpu_count']} CPUs, jax {result['jax']} "
        f"({result['backend']}); date {result['date']}",
        f"- episodes: {args.episodes} per advisor, setting and arena: the evaluation episodes "
        f"of eval seed {args.eval_seed} (those every agent of a study with that eval_seed "
        "is scored on); each advisor alone through the trainer's interface "
        "(docs/advisors.md), deterministic apart from its knobs' own draws",
        *(f"- {note}" for note in args.notes),
        "",
        *writing.markdown_table(header, table, align="llr"),
    ]


if __name__ == "__main__":
    main(tyro.cli(Args))
