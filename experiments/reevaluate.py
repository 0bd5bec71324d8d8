"""Evaluate every agent of finished runs on another episode set (``--eval-seed``).

``advisor-jax train`` evaluates a run's agents on the episodes of its ``--eval-seed`` (the
first seed unless given). Runs trained apart with different eval seeds cannot be pooled or
paired on their eval.json; this evaluates their saved actors again, on the episodes any
other run with that eval seed used, and writes ``eval_seed<S>.json`` (eval.json's format)
into each run directory, or into ``--out``.

    python experiments/reevaluate.py runs/A runs/B --eval-seed 8 --episodes 50
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

from advisor_jax.fileio import atomic_write_json
from advisor_jax.training.run_directory import reevaluate


def main(argv: list[str] | None = None) -> None:
    parser = argparse.ArgumentParser(
        description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter
    )
    parser.add_argument("runs", type=Path, nargs="+", help="finished run directories")
    parser.add_argument("--eval-seed", type=int, required=True)
    parser.add_argument("--episodes", type=int, default=100, help="episodes per arena")
    parser.add_argument("--arenas", nargs="+", default=[],
                        help="default: the arenas of each run's own evaluation")  # fmt: skip
    parser.add_argument("--out", type=Path, help="directory for the files (default: each run)")
    args = parser.parse_args(argv)
    for run in args.runs:
        result = reevaluate(run, args.eval_seed, args.episodes, tuple(args.arenas))
        where = (args.out / run.name) if args.out else run
        atomic_write_json(where / f"eval_seed{args.eval_seed}.json", result)
        means = {
            arena: 100 * sum(v for v in r["success"] if v is not None) / len(r["success"])
            for arena, r in result.items()
        }
        print(f"{run}: eval seed {args.eval_seed}, success % " + ", ".join(
            f"{a} {m:.1f}" for a, m in means.items()), file=sys.stderr)  # fmt: skip


if __name__ == "__main__":
    main()
