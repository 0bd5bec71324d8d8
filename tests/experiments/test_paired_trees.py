"""experiments/paired_trees.py: one population trained by two checkouts, paired by seed.

The reference checkout here is a stand-in whose ``advisor-jax train`` copies a kept run into
``--out`` and notes where its package was imported from: the pairing and the bookkeeping
are tested without training."""

from __future__ import annotations

import json
import shutil
from pathlib import Path

import pytest

from tests.experiments.scripts import load_script

paired_trees = load_script("paired_trees")
KEPT_RUN = Path(__file__).resolve().parents[2] / "results/table1_stable/run_data/ATD3_AfDP"

FAKE_MAIN = f"""
import shutil, sys
from pathlib import Path
import advisor_jax

def main():
    out = Path(sys.argv[sys.argv.index("--out") + 1])
    shutil.copytree({str(KEPT_RUN)!r}, out, dirs_exist_ok=True)
    (out / "imported_from.txt").write_text(advisor_jax.__file__)
    (out / "argv.txt").write_text(" ".join(sys.argv[1:]))
    (out / "cwd.txt").write_text(str(Path.cwd()))
"""


def _reference(root: Path) -> Path:
    (root / "advisor_jax" / "cli").mkdir(parents=True)
    (root / "advisor_jax" / "__init__.py").write_text("")
    (root / "advisor_jax" / "cli" / "__init__.py").write_text("")
    (root / "advisor_jax" / "cli" / "main.py").write_text(FAKE_MAIN)
    return root


def test_the_control_trains_with_the_reference_and_the_finished_sides_are_paired(tmp_path):
    tree, out = _reference(tmp_path / "ref"), tmp_path / "out"
    options = ["--reference", str(tree), "--out", str(out)]
    train = ["--preset", "stable", "--seeds", "4"]

    assert paired_trees.main([*options, "--sides", "control", "--", *train]) == {}
    control = out / "control"
    imported = Path((control / "imported_from.txt").read_text()).resolve()
    assert imported == (tree / "advisor_jax" / "__init__.py").resolve()
    assert (control / "cwd.txt").read_text() == str(Path.cwd())  # where relative paths were written
    assert (control / "argv.txt").read_text() == f"train {' '.join(train)} --out {control}"
    record = json.loads((control / "command.json").read_text())
    assert record["checkout"] == str(tree.resolve()) and record["commit"] is None

    # the treatment as a copy of the same run, trained with these options: kept, not trained
    shutil.copytree(control, out / "treatment")
    pages = paired_trees.main([*options, "--", *train])
    assert set(pages) == {"paired"}  # no --null: no second treatment, no null pairing
    arenas = pages["paired"]["arenas"]
    assert set(arenas) == {"training", "validation"}
    for arena in arenas.values():
        assert set(arena["differences"]) == {0.0}
    assert pages["paired"]["same_episodes"]["identical_seeds"] == arenas["training"]["seeds"]
    assert "experiments/paired_trees.py" in (out / "paired.md").read_text()


def test_a_finished_side_trained_with_other_options_is_refused_not_paired(tmp_path):
    tree, out = _reference(tmp_path / "ref"), tmp_path / "out"
    options = ["--reference", str(tree), "--out", str(out)]
    paired_trees.main([*options, "--sides", "control", "--", "--preset", "stable", "--seeds", "4"])
    shutil.copytree(out / "control", out / "treatment")
    with pytest.raises(SystemExit, match="was trained with `--preset stable --seeds 4`, not "
                                         "`--preset stable --seeds 8`"):  # fmt: skip
        paired_trees.main([*options, "--", "--preset", "stable", "--seeds", "8"])
    assert not (out / "paired.md").exists()
    (out / "treatment" / "command.json").unlink()  # a finished run that names no options
    with pytest.raises(SystemExit, match="treatment was trained with options it does not record"):
        paired_trees.main([*options, "--", "--preset", "stable", "--seeds", "4"])


def test_an_unfinished_side_is_named_not_overwritten(tmp_path):
    tree, out = _reference(tmp_path / "ref"), tmp_path / "out"
    (out / "control").mkdir(parents=True)
    (out / "control" / "train_log.jsonl").write_text("{}\n")
    with pytest.raises(SystemExit, match="an unfinished run is there"):
        paired_trees.main(["--reference", str(tree), "--out", str(out), "--sides", "control"])
    assert (out / "control" / "train_log.jsonl").read_text() == "{}\n"


@pytest.mark.parametrize(
    "bad, message",
    [(["--", "--out", "x"], "give --out before `--`"),
     (["--reference", "/nonexistent"], "/nonexistent: no advisor_jax package there")],
)  # fmt: skip
def test_bad_options_are_refused(tmp_path, bad, message, capsys):
    tree = _reference(tmp_path / "ref")
    with pytest.raises(SystemExit):
        paired_trees.main(["--reference", str(tree), "--out", str(tmp_path / "o"), *bad])
    assert message in capsys.readouterr().err
    assert not (tmp_path / "o").exists()
