"""Writing a measurement down: markdown tables, the command that reproduces it, atomic files."""

from __future__ import annotations

import argparse
import os
import shlex
import sys
from collections.abc import Callable, Iterable, Sequence
from pathlib import Path
from typing import Any

from advisor_jax.fileio import atomic_write_json, atomic_write_text


def markdown_table(
    header: Sequence[str],
    rows: Iterable[Sequence[Any]],
    formats: Sequence[str] = (),
    align: str = "lr",
) -> list[str]:
    """A markdown table as lines. ``formats``: a spec per column for ``format()`` (".1f",
    ",.0f"; "": ``str``); ``align``: "l" or "r" per column. In both the last entry stands for
    the columns after it: ``align="lr"`` is a label then numbers, ``formats=("", ".1f")`` a
    label then numbers to one decimal."""
    width = len(header)
    align = (align + align[-1] * width)[:width]
    specs = (*formats, *[formats[-1] if formats else ""] * width)[:width]
    lines = [
        "| " + " | ".join(header) + " |",
        "|" + "|".join("---:" if a == "r" else "---" for a in align) + "|",
    ]
    for row in rows:
        cells = (format(cell, spec) for cell, spec in zip(row, specs, strict=True))
        lines.append("| " + " | ".join(cells) + " |")
    return lines


def changed_options(
    parser: argparse.ArgumentParser, args: argparse.Namespace, skip: Iterable[str] = ("out",)
) -> list[str]:
    """The command-line options of ``args`` that differ from ``parser``'s defaults, as argv:
    a command line that reproduces the run without restating every default."""
    argv = []
    for key, value in vars(args).items():
        if key in skip or value == parser.get_default(key):
            continue
        flag = "--" + key.replace("_", "-")
        if value is True:
            argv.append(flag)
        elif isinstance(value, list | tuple):
            argv += [flag, *map(str, value)]
        else:
            argv += [flag, str(value)]
    return argv


def command_line(script: str, argv: Sequence[str], scheduling: bool = False) -> str:
    """``python SCRIPT ARGV...``, quoted for a shell, for a report's "Command:" line. With
    ``scheduling`` also the ``nice`` and ``taskset`` the process runs under (latency on a
    CPU depends on them)."""
    command = shlex.join(["python", script, *map(str, argv)])
    if scheduling:
        if os.nice(0) != 0:
            command = f"nice -n {os.nice(0)} {command}"
        cpus = sorted(os.sched_getaffinity(0))
        if len(cpus) < (os.cpu_count() or 0):
            command = f"taskset -c {','.join(map(str, cpus))} {command}"
    return command


def write_markdown(path: str | os.PathLike, lines: Sequence[str], echo: bool = False) -> None:
    """Writes ``lines`` as one markdown file ending in one newline, atomically (a reader never
    sees half a report), says where on stderr and, with ``echo``, prints it."""
    text = "\n".join(lines).rstrip("\n") + "\n"
    atomic_write_text(path, text)
    print(f"wrote {path}", file=sys.stderr)
    if echo:
        print(text, end="")


def check_parser(doc: str) -> argparse.ArgumentParser:
    """The options of a parity check of the learner at paper sizes (``experiments/``:
    ``--agents``, ``--updates``, ``--precision``, ``--small``, ``--out``), described by the
    first paragraph of the script's ``doc``."""
    parser = argparse.ArgumentParser(description=doc.split("\n\n")[0])
    parser.add_argument("--agents", type=int, default=8)
    parser.add_argument("--updates", type=int, default=9, help="updates of the parity check")
    parser.add_argument("--precision", nargs="+", default=["bf16", "fp32"])
    parser.add_argument("--small", action="store_true", help="tiny networks (CPU smoke run)")
    parser.add_argument("--out", default=None, help="folder for the .md and .json report")
    return parser


def _positive(text: str) -> int:
    value = int(text)
    if value < 1:
        raise argparse.ArgumentTypeError(f"{value} must be ≥ 1")
    return value


def layers_parser(doc: str) -> argparse.ArgumentParser:
    """The options of a GEMM benchmark over a batch of layers (``experiments/``: ``--layers``,
    ``--out``), described by ``doc``'s first paragraph."""
    parser = argparse.ArgumentParser(
        description=doc.split("\n\n")[0], formatter_class=argparse.RawDescriptionHelpFormatter
    )
    parser.add_argument("--layers", type=_positive, default=128,
                        help="matrices per call: agents × twin critics (128)")  # fmt: skip
    parser.add_argument("--out", type=Path, default=Path("results"))
    return parser


def publish_result(
    out: str | os.PathLike,
    name: str,
    result: dict,
    report: Callable[[dict, str], Sequence[str]],
    argv: Sequence[str] | None = None,
) -> None:
    """An experiment's ``result`` as ``out/name.json``, and ``report(result, command)`` as
    ``out/name.md``, where the command is ``python experiments/name.py`` with ``argv`` (the
    process's arguments when None)."""
    argv = sys.argv[1:] if argv is None else argv
    atomic_write_json(Path(out) / f"{name}.json", result)
    write_markdown(
        Path(out) / f"{name}.md", report(result, command_line(f"experiments/{name}.py", argv))
    )


def publish_check(
    out: str | os.PathLike | None,
    script: str,
    argv: Sequence[str] | None,
    title: str,
    setup: str,
    table: Sequence[str],
    rows: list[dict[str, Any]],
) -> None:
    """A check script's report: ``# title``, the ``setup`` sentence followed by the device,
    jax and date (``measure.provenance``), the ``table`` and the command that reproduces it
    (``script`` with ``argv``; None: this process's arguments). Printed when ``out`` is
    None; else written as ``out/NAME.md`` (and echoed) and ``out/NAME.json`` (provenance,
    command and ``rows``), NAME being the script's file name without ``.py``."""
    from advisor_jax.bench import measure

    info = measure.provenance()
    command = command_line(script, sys.argv[1:] if argv is None else argv)
    device = f"{info['device']} ({info['backend']}), jax {info['jax']}, {info['date']}."
    lines = [f"# {title}", "", f"{setup}; {device}", "", *table, "", f"Command: `{command}`"]
    if out is None:
        print("\n".join(lines))
        return
    name = os.path.splitext(os.path.basename(script))[0]
    write_markdown(os.path.join(out, f"{name}.md"), lines, echo=True)
    atomic_write_json(os.path.join(out, f"{name}.json"), dict(info, command=command, rows=rows))
