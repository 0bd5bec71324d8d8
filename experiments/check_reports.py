"""Regenerates every kept report under results/ and checks it still says the same.

    python experiments/check_reports.py            # every results/**/report.md
    python experiments/check_reports.py results/paper/report.md ...

Each ``report.md`` names the ``advisor-jax report`` command that made it. This runs that
command into a temporary folder and compares each JSON file it writes with the kept one,
leaving out the command itself and the day it ran: a report that no longer regenerates
equal (kept run data thinned too far, a code change that moved a number or a label) is
listed with the first difference, and the exit status is 1. Nothing in results/ is
written.
"""

from __future__ import annotations

import argparse
import json
import re
import shlex
import subprocess
import sys
import tempfile
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
COMMAND = re.compile(r"Command: `(advisor-jax report [^`]*)`")
VOLATILE = ("report_command", "reported")  # where and on which day the report was written


def comparable(value):
    """``value`` without the keys that name where the report was written."""
    if isinstance(value, dict):
        return {k: comparable(v) for k, v in value.items() if k not in VOLATILE}
    if isinstance(value, list):
        return [comparable(v) for v in value]
    return value


def first_difference(new, old, where: str = "") -> str | None:
    """The path of the first place ``new`` and ``old`` differ, with both values."""
    if isinstance(new, dict) and isinstance(old, dict):
        for key in sorted(set(new) | set(old)):
            if key not in new or key not in old:
                return f"{where}.{key}: only in the {'kept' if key in old else 'new'} file"
            found = first_difference(new[key], old[key], f"{where}.{key}")
            if found:
                return found
        return None
    if isinstance(new, list) and isinstance(old, list):
        if len(new) != len(old):
            return f"{where}: {len(new)} items, kept {len(old)}"
        for i, (a, b) in enumerate(zip(new, old, strict=True)):
            found = first_difference(a, b, f"{where}[{i}]")
            if found:
                return found
        return None
    return None if new == old else f"{where}: {new!r}, kept {old!r}"


def check(report: Path) -> list[str]:
    """Problems with one report (empty: it regenerates equal)."""
    found = COMMAND.search(report.read_text())
    if found is None:
        return ["no `advisor-jax report` command in it"]
    words = shlex.split(found.group(1))
    at = words.index("--out") + 1
    kept = ROOT / words[at]
    with tempfile.TemporaryDirectory() as tmp:
        words[at] = tmp
        done = subprocess.run(words, cwd=ROOT, capture_output=True, text=True)
        if done.returncode:
            return [f"the command failed: {done.stderr.strip().splitlines()[-1:]}"]
        problems = []
        for new in sorted(Path(tmp).glob("*.json")):
            old = kept / new.name
            if not old.is_file():
                problems.append(f"{new.name}: not kept")
                continue
            diff = first_difference(
                comparable(json.loads(new.read_text())), comparable(json.loads(old.read_text()))
            )
            if diff:
                problems.append(f"{new.name}{diff}")
        return problems


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("reports", nargs="*", type=Path, help="report.md files (default: all)")
    args = parser.parse_args(argv)
    reports = args.reports or sorted((ROOT / "results").rglob("report.md"))
    failed = 0
    for report in reports:
        problems = check(report.resolve())
        name = report.resolve().relative_to(ROOT)
        print(f"{name}: {'equal' if not problems else 'DIFFERS'}", flush=True)
        for p in problems:
            print(f"    {p}")
        failed += bool(problems)
    print(f"{len(reports) - failed} of {len(reports)} reports regenerate equal")
    return 1 if failed else 0


if __name__ == "__main__":
    sys.exit(main())
