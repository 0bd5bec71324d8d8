"""Does a change to how the program computes leave training where it was? One population
trained by the checkout before the change and by this one, paired seed by seed.

A speed change (a kernel, a layout, a compiler option) changes no setting, so
``advisor-jax report --versus`` cannot see it. Its check is the same population trained
twice, on the same seeds and evaluation episodes: CONTROL by the code before the change
(``--reference TREE``: ``git worktree add /tmp/ref HEAD~1``, or an untracked copy of that
commit) and TREATMENT by this checkout, each seed's success paired as ``paired_runs.py``
pairs two runs. ``--null`` also trains TREATMENT_AGAIN, this checkout a second time: what two
runs of one program differ by (a GPU does not always repeat itself bit for bit), the
yardstick the first pairing is read against.

    python experiments/paired_trees.py --reference /tmp/ref --out OUT -- \\
        --preset stable --agent ATD3+AfDP --seeds 32 --seed 200 --precision bf16 \\
        --eval-episodes 50 --checkpoint-every 0 --drop-checkpoints --no-progress
    python experiments/paired_trees.py --reference /tmp/ref --null --sides treatment_again \\
        --out OUT -- ...                   # the null's second run, in a later command

Everything after ``--`` goes to ``advisor-jax train`` as given (all but ``--out``). Each
side trains in a process of its own whose imports resolve to its checkout (relative paths in
the options are read from the folder this runs in), one after another, into OUT/<side>/,
with OUT/<side>/command.json naming the checkout and its commit. A side whose run.json says
finished is kept, not trained again, so that a later call (with OUT copied back) goes on
where an earlier one stopped, if it gives the same train options (a finished side trained
with others is refused); ``--sides`` trains only those named. Then every pair whose two runs
are there is written: OUT/paired.{md,json} (TREATMENT − CONTROL) and
OUT/paired_null.{md,json} (TREATMENT_AGAIN − TREATMENT).

A pairing reads each side's run.json, eval.json and metrics.npz; ``--drop-checkpoints`` spares
the disk (and a copy back from another machine) each side's replay buffers: 843 MiB at 48
``stable`` agents, where the pairing's files are about 1 MB. Both checkouts must know every
option given: a reference older than commit 7495866 refuses ``--drop-checkpoints``.
"""

from __future__ import annotations

import argparse
import datetime
import json
import shlex
import subprocess
import sys
from pathlib import Path

from advisor_jax.bench import measure, writing
from advisor_jax.fileio import atomic_write_json

sys.path.insert(0, str(Path(__file__).resolve().parent))
from paired_runs import write_pairing  # noqa: E402

HERE = Path(__file__).resolve().parents[1]
SIDES = ("control", "treatment", "treatment_again")
PAIRS = (("paired", "control", "treatment"), ("paired_null", "treatment", "treatment_again"))
"""(page name, its control side, its treatment side)."""
TRAIN = "from advisor_jax.cli.main import main; main()"


def finished(run: Path) -> bool:
    """Whether ``run`` holds a run that trained to its end."""
    path = run / "run.json"
    return path.is_file() and json.loads(path.read_text()).get("status") == "finished"


def commit_of(tree: Path) -> str | None:
    """``tree``'s git commit, or None where ``tree`` is not the top of a git checkout (an
    untracked copy inside another checkout has no commit of its own)."""
    found = subprocess.run(["git", "-C", str(tree), "rev-parse", "--show-toplevel", "HEAD"],
                           capture_output=True, text=True, check=False)  # fmt: skip
    lines = found.stdout.split()
    if found.returncode != 0 or len(lines) != 2 or Path(lines[0]).resolve() != tree.resolve():
        return None
    return lines[1]


def trained_with(run: Path) -> list[str] | None:
    """The ``advisor-jax train`` options ``run`` was trained with (its command.json, less
    ``--out``), or None where it names none."""
    path = run / "command.json"
    if not path.is_file():
        return None
    words = shlex.split(json.loads(path.read_text())["command"])[2:]  # past `advisor-jax train`
    return words[:-2] if words[-2:-1] == ["--out"] else words


def check_kept(out: Path, train_args: list[str]) -> None:
    """Refuse finished sides in ``out`` trained with other options than ``train_args``: a page
    would pair them under this command (another seed count, another preset)."""
    for side in SIDES:
        if finished(out / side) and (got := trained_with(out / side)) != train_args:
            was = "options it does not record" if got is None else f"`{shlex.join(got)}`"
            raise SystemExit(
                f"{out / side} was trained with {was}, not `{shlex.join(train_args)}`: give its "
                "options after `--`, or another --out"
            )


def train(tree: Path, train_args: list[str], run: Path) -> None:
    """``advisor-jax train TRAIN_ARGS --out RUN`` with ``tree``'s code, and its command.json."""
    if run.exists() and any(run.iterdir()):
        raise SystemExit(
            f"{run}: an unfinished run is there; continue it with `advisor-jax train --resume "
            f"--out {run}` in {tree}, or move it away"
        )
    started = datetime.datetime.now(datetime.UTC).isoformat(timespec="seconds")
    # -P: the working folder is not put on the import path, so PYTHONPATH's checkout comes
    # first and the process stays here, where relative paths in TRAIN_ARGS were written.
    command = [sys.executable, "-P", "-c", TRAIN, "train", *train_args, "--out", str(run)]
    subprocess.run(command, check=True, env=measure.checkout_env(tree))
    record = dict(
        command=shlex.join(["advisor-jax", "train", *train_args, "--out", str(run)]),
        checkout=str(tree), commit=commit_of(tree), created=started,
    )  # fmt: skip
    atomic_write_json(run / "command.json", record)


def main(argv=None) -> dict:
    argv = sys.argv[1:] if argv is None else list(argv)
    cut = argv.index("--") if "--" in argv else len(argv)
    ours, train_args = argv[:cut], argv[cut + 1 :]
    parser = argparse.ArgumentParser(
        description=__doc__.split("\n\n")[0], formatter_class=argparse.RawDescriptionHelpFormatter
    )
    parser.add_argument(
        "--reference", type=Path, required=True, metavar="TREE",
        help="the checkout that trains CONTROL: the code before the change",
    )  # fmt: skip
    parser.add_argument("--out", type=Path, required=True)
    parser.add_argument("--null", action="store_true", help="also train TREATMENT_AGAIN")
    parser.add_argument("--sides", nargs="+", choices=SIDES, help="train only these sides")
    parser.add_argument("--eval-seed", type=int, default=None)
    args = parser.parse_args(ours)
    if "--out" in train_args or any(a.startswith("--out=") for a in train_args):
        parser.error("give --out before `--`: each side's run goes into OUT/<side>")
    reference = args.reference.resolve()
    if not (reference / "advisor_jax" / "__init__.py").is_file():
        parser.error(f"--reference {reference}: no advisor_jax package there")
    trees = dict(control=reference, treatment=HERE, treatment_again=HERE)
    wanted = args.sides or [s for s in SIDES if args.null or s != "treatment_again"]
    out = args.out.resolve()
    check_kept(out, train_args)
    for side in wanted:
        if finished(out / side):
            print(f"{side}: finished in {out / side}, kept", flush=True)
            continue
        print(f"{side}: training with {trees[side]}", flush=True)
        train(trees[side], train_args, out / side)
    command = writing.command_line("experiments/paired_trees.py", argv)
    pages = {}
    for name, control, treatment in PAIRS:
        if finished(out / control) and finished(out / treatment):
            pages[name], page = write_pairing(
                out / control, out / treatment, out, command, args.eval_seed, name
            )
            print(page, flush=True)
    return pages


if __name__ == "__main__":
    main()
