"""``--reference TREE`` of the benchmarks (experiments/run_reference): the other
checkout's script runs with the same options, its imports resolve to that checkout and not
to this one, its report comes back; bench_train.py pairs its rows with this tree's."""

from __future__ import annotations

import json
import sys
from pathlib import Path

import pytest

from advisor_jax.bench.measure import run_reference
from tests.experiments.scripts import load_script

bench_train = load_script("bench_train")

# A stand-in for experiments/<script> of another checkout: it reports its argv and where
# ``advisor_jax`` was imported from.
FAKE_SCRIPT = """
import argparse, json, sys
from pathlib import Path
import advisor_jax
parser = argparse.ArgumentParser()
parser.add_argument("--out", type=Path)
args, rest = parser.parse_known_args()
report = dict(rows=[{"agents": 1}], argv=rest, package=advisor_jax.__file__)
(args.out / "fake.json").write_text(json.dumps(report))
"""


def _tree(root: Path) -> Path:
    (root / "experiments").mkdir(parents=True)
    (root / "experiments" / "fake.py").write_text(FAKE_SCRIPT)
    (root / "advisor_jax").mkdir()
    (root / "advisor_jax" / "__init__.py").write_text("")
    return root


def test_the_reference_runs_with_its_own_package_and_our_options(tmp_path):
    tree = _tree(tmp_path / "ref")
    report = run_reference(tree, "fake.py", ["--agents", "1", "64"], "fake.json")
    assert report["rows"] == [{"agents": 1}]
    assert report["argv"] == ["--agents", "1", "64"]
    assert Path(report["package"]).resolve() == (tree / "advisor_jax" / "__init__.py").resolve()


def test_a_tree_without_the_script_is_named(tmp_path):
    with pytest.raises(SystemExit, match="no experiments/bench_train.py"):
        run_reference(tmp_path, "bench_train.py", [], "bench_train.json")


def test_bench_train_pairs_rows_by_agents_devices_and_precision():
    rows = [
        dict(agents=1, devices=1, precision="bf16", agent_steps_per_s=300.0),
        dict(agents=64, devices=1, precision="bf16", agent_steps_per_s=900.0),
        dict(agents=64, devices=1, precision="fp32", agent_steps_per_s=500.0),  # not in ref
    ]
    reference = dict(rows=[
        dict(agents=64, devices=1, precision="bf16", agent_steps_per_s=600.0),
        dict(agents=1, devices=1, precision="bf16", agent_steps_per_s=200.0),
    ])  # fmt: skip
    lines = bench_train.reference_lines(rows, reference, Path("ref"))
    body = [line for line in lines if line.startswith("| bf16") or line.startswith("| fp32")]
    assert body == [
        "| bf16 | 1 | 1 | 200 | 300 | 1.50 |",
        "| bf16 | 64 | 1 | 600 | 900 | 1.50 |",
    ]
    assert bench_train.reference_lines(rows, None, None) == []


def test_the_report_records_its_command(tmp_path, monkeypatch):
    # Each row of results/bench_train.json (and bench_multigpu.json) names its command.
    argv = ["--preset", "quick", "--agents", "1", "--chunk", "2", "--repeats", "1", "--out"]
    monkeypatch.setattr(sys, "argv", ["bench_train.py", *argv, str(tmp_path)])
    bench_train.main()
    record = json.loads((tmp_path / "bench_train.json").read_text())
    command = record["command"]
    assert command == f"python experiments/bench_train.py {' '.join(argv)} {tmp_path}"
    assert f"Command: `{command}`" in (tmp_path / "bench_train.md").read_text()
    # --program auto (the default) is recorded as asked, each row as the program that ran
    assert record["program"] == "auto" and record["rows"][0]["program"] == "general"
    assert "| general |" in (tmp_path / "bench_train.md").read_text()
