"""``advisor-jax report``: the paper's tables and figures from finished runs."""

from __future__ import annotations

import dataclasses
import shlex
from pathlib import Path
from typing import Annotated

import tyro
from rich.console import Console

from advisor_jax.cli.helptext import flowing


@flowing
@dataclasses.dataclass(frozen=True)
class ReportArgs:
    """Pool the finished runs below DIR... and write each paper item they support.

    Each item is OUT/<item>.png and OUT/<item>.json (its numbers, with the runs, devices,
    dates and commands behind them); OUT/report.md shows them all. Items: table1, table2
    (Tables 2-3), fig6, fig7, fig8, fig9, fig10, fig11, eps, afp, versus, collapse; one
    with no matching runs is skipped with a note. Runs must share their evaluation
    episodes (eval seed, episode count, arenas) per training arena, or the report refuses.

    Examples:
      advisor-jax report runs/quick --out reports/quick
      advisor-jax report results/table1_stable/run_data results/table1_stable/run_data_d2 \
          --out results/table1 --items table1 fig8 fig9 fig10
      advisor-jax report results/table1_stable --versus clip_q_target=1 --items versus
    """

    dirs: Annotated[
        tuple[Path, ...],
        tyro.conf.Positional,
        tyro.conf.arg(metavar="DIR...", help_behavior_hint="(required)"),
    ]
    """Folders of run directories (advisor-jax sweep's --out, train's runs, kept run data)."""
    out: Annotated[Path, tyro.conf.arg(metavar="OUT")]
    """Where the PNG and JSON files go."""
    items: tuple[str, ...] = ()
    """Only these items (default: every item the runs support)."""
    versus: tuple[str, ...] = ()
    """Settings to compare seed by seed, NAME or NAME=VALUE (VALUE: the treatment's), e.g.
    --versus clip_q_target=1 precision=bf16: pairs of points that differ in NAME alone."""
    eval_seed: int | None = None
    """Use every run's evaluation on this seed's episodes (eval.json or eval_seed<S>.json;
    default: the seed all runs share)."""
    keep_runs: Path | None = None
    """Also copy the compact run data of every run used (JSON files and a compressed
    metrics.npz; no parameters or replay buffers) into this folder."""


def report_command(args: ReportArgs) -> None:
    """Entry point of ``advisor-jax report``."""
    if not args.dirs:
        raise ValueError("name at least one DIR of runs")
    from advisor_jax.analysis.report import make_report  # imports matplotlib: keep --help fast

    console = Console(stderr=True, highlight=False)
    command = shlex.join(
        ["advisor-jax", "report", *map(str, args.dirs), "--out", str(args.out)]
        + (["--items", *args.items] if args.items else [])
        + (["--versus", *args.versus] if args.versus else [])
        + (["--eval-seed", str(args.eval_seed)] if args.eval_seed is not None else [])
    )
    written = make_report(
        args.dirs,
        args.out,
        args.items,
        args.eval_seed,
        args.versus,
        command,
        say=lambda m: console.print(m),
    )
    if args.keep_runs is not None:
        from advisor_jax.analysis.rundata import compact_run
        from advisor_jax.analysis.runs import load_runs

        for run in load_runs(args.dirs, args.eval_seed).runs:
            root = next(d for d in args.dirs if run.path.is_relative_to(d))
            compact_run(run.path, args.keep_runs / root.name / run.path.relative_to(root))
        console.print(f"compact run data in {args.keep_runs}")
    noun = "file" if len(written) == 1 else "files"
    console.print(f"wrote {len(written)} {noun} into {args.out} (report.md lists them)")
