"""``advisor-jax report DIR... --out R``: the paper's items from whatever runs are given.

Loads every finished run below the DIRs (``runs.load_runs``: one loader, one evaluation set
per training arena or a refusal), pools them into points (``runs.pool``) and draws each
item that the points support; an item with no matching points is skipped with a note.
Every item is ``R/<item>.png`` and ``R/<item>.json`` (its numbers, the runs it rests on,
their devices and dates, the commands that trained them and the one that drew it);
``R/report.md`` shows them all with their tables.

Items: table1, table2 (Tables 2-3), fig6, fig7, fig8, fig9, fig10, fig11, eps (success over
the ε schedule), afp (the advisor in policy updating against its control, by β), versus
(settings compared seed by seed: ``--versus NAME[=VALUE]``), collapse (seeds below the
advisor and the learner's diagnostics), advisor_quality (each agent's success against its
advisor's own, from runs trained with ``--eval-advisor``).
"""

from __future__ import annotations

import dataclasses
import datetime
import math
from collections.abc import Sequence
from pathlib import Path

import numpy as np

from advisor_jax import __version__
from advisor_jax.analysis.items import (
    advisor_quality,
    collapse,
    curves,
    sweeps,
    table1,
    table2,
    versus,
)
from advisor_jax.analysis.items.base import Item, in_both_arenas, point_summary
from advisor_jax.analysis.runs import load_runs, pool
from advisor_jax.fileio import atomic_write_json, atomic_write_text
from advisor_jax.training.plots import save_png

FIGURE_DPI = 90  # figures for a screen; results/ stays small (README: keep it under 20 MB)

ITEMS = {
    "table1": table1.table1,
    "table2": table2.table2,
    "fig6": sweeps.fig6,
    "fig7": sweeps.fig7,
    "fig8": curves.fig8,
    "fig9": curves.fig9,
    "fig10": curves.fig10,
    "fig11": sweeps.fig11,
    "eps": sweeps.eps,
    "afp": versus.afp,
    "versus": versus.versus,
    "collapse": collapse.collapse,
    "advisor_quality": advisor_quality.advisor_quality,
}


@dataclasses.dataclass(frozen=True)
class Context:
    """What items need beside the points."""

    advisors: dict  # {arena: advisor evaluation}
    versus: tuple[str, ...] = ()


def provenance(item: Item, command: str) -> dict:
    """Where an item's numbers come from: runs, devices, dates, evaluation, commands."""
    runs = list({id(s.run): s.run for p in item.points for s in p.seeds.values()}.values())
    commands = list(dict.fromkeys(r.command for r in runs if r.command))
    return {
        "runs": sorted(str(r.path) for r in runs),
        "devices": sorted({r.summary.get("device", "?") for r in runs}),
        "trained": sorted({r.summary.get("created", "?")[:10] for r in runs}),
        "evaluation": sorted({(r.eval_seed, ep) for r in runs for _, ep in r.evaluated_on[1]}),
        "training_commands": commands,
        "report_command": command,
        "reported": datetime.date.today().isoformat(),
        "advisor_jax_version": __version__,
    }


JSON_DIGITS = 6  # significant digits of a float in an item's JSON: rates measured in float32


def _strict(x):
    """NaN and infinities → None, tuples → lists: strict JSON; floats rounded to
    ``JSON_DIGITS`` significant digits (0.5349999908357859 → 0.535: what float32 run data
    holds, at a third of the size)."""
    if isinstance(x, dict):
        return {str(k): _strict(v) for k, v in x.items()}
    if isinstance(x, list | tuple | np.ndarray):
        return [_strict(v) for v in x]
    if isinstance(x, np.generic):
        x = x.item()
    if isinstance(x, float):
        return float(f"{x:.{JSON_DIGITS}g}") if math.isfinite(x) else None
    return x


def _one_arena(points) -> str:
    """Why the simulation items may have skipped runs: they were scored in one arena only."""
    partial = sorted({p.text() for p in points if p.arena != "physical" and not in_both_arenas(p)})
    if not partial:
        return ""
    return (
        f" ({len(partial)} point(s), e.g. {partial[0]}, were evaluated in one arena only; "
        "Table 1 and Figs 6-11 need the training and validation arenas: train with "
        "--eval-arenas training validation)"
    )


def make_report(
    dirs: Sequence[Path],
    out: Path,
    items: Sequence[str] = (),
    eval_seed: int | None = None,
    versus_settings: Sequence[str] = (),
    command: str = "",
    say=print,
) -> list[Path]:
    """Writes the items into ``out``; returns the files written."""
    unknown = [name for name in items if name not in ITEMS]
    if unknown:
        raise ValueError(f"unknown item {unknown[0]!r}; choose from {', '.join(ITEMS)}")
    runset = load_runs(dirs, eval_seed)
    if not runset.runs:
        raise ValueError(f"no finished runs under {', '.join(map(str, dirs))}")
    points, notes = pool(runset)
    notes = runset.notes + notes
    context = Context(runset.advisors, tuple(versus_settings))
    out.mkdir(parents=True, exist_ok=True)
    written, sections = [], []
    one_arena = _one_arena(points)
    for name in items or ITEMS:
        item = ITEMS[name](points, context)
        if item is None:
            notes.append(f"{name}: skipped, no points it applies to{one_arena}")
            continue
        record = {
            "item": item.name,
            "title": item.title,
            "points": [point_summary(p) for p in item.points],  # an item may give its own
            **item.record,
            "provenance": provenance(item, command),
        }
        json_file = out / f"{item.name}.json"
        written.append(atomic_write_json(json_file, _strict(record), compact_lists=True))
        if item.figure is not None:
            written.append(save_png(item.figure, out / f"{item.name}.png", dpi=FIGURE_DPI))
        sections += _section(item, record["provenance"])
        say(f"{item.name}: {item.title}")
    lines = [
        f"# Report: {', '.join(map(str, dirs))}",
        "",
        f"{len(runset.runs)} runs, {len(points)} points. Command: `{command}`",
        "",
        *sections,
    ]
    if notes:
        lines += ["## Notes", "", *(f"- {n}" for n in notes), ""]
    for note in notes:
        say(f"note: {note}")
    written.append(atomic_write_text(out / "report.md", "\n".join(lines).rstrip() + "\n"))
    return written


def _section(item: Item, prov: dict) -> list[str]:
    evaluation = ", ".join(f"eval seed {s}, {n} episodes" for s, n in prov["evaluation"])
    lines = [f"## {item.title}", "", *item.lines]
    if item.figure is not None:
        lines += [f"![{item.title}]({item.name}.png)", ""]
    lines += [
        f"Trained on {', '.join(prov['devices'])} ({', '.join(prov['trained'])}); evaluation: "
        f"{evaluation} per arena. Numbers: `{item.name}.json`.",
        "",
    ]
    if prov["training_commands"]:
        lines += ["Training commands:", "", *(f"- `{c}`" for c in prov["training_commands"]), ""]
    return lines
