"""docs/advisors.md's example advisor, exactly as printed there: written to a module in the
current directory, named on the command line's form MODULE:ATTRIBUTE, checked, trained with
(a tiny population, its quality knobs as a grid), recorded in run.json; changed, the run is
not resumed."""

from __future__ import annotations

import dataclasses
import json
import re
import sys
from pathlib import Path

import numpy as np
import pytest

from advisor_jax.training.host_loop import run_training
from tests.training.conftest import RUN_HP, TINY

DOCS = Path(__file__).resolve().parents[2] / "docs" / "advisors.md"


def example_source() -> str:
    """The docs' python block that defines ``advisor``."""
    blocks = re.findall(r"```python\n(.*?)```", DOCS.read_text(), flags=re.S)
    found = [b for b in blocks if "\nadvisor = AdvisorPlugin(" in b]
    assert len(found) == 1, "docs/advisors.md should hold one example module"
    return found[0]


@pytest.fixture
def example_module(tmp_path, monkeypatch):
    (tmp_path / "my_advisors.py").write_text(example_source())
    monkeypatch.chdir(tmp_path)
    yield tmp_path / "my_advisors.py"
    sys.modules.pop("my_advisors", None)
    if str(tmp_path) in sys.path:
        sys.path.remove(str(tmp_path))


def test_the_documented_example_trains_and_is_recorded(example_module, tmp_path):
    cfg = dataclasses.replace(TINY, episodes=2, snapshot_episodes=(), advisor="my_advisors:advisor")
    out = tmp_path / "run"
    summary = run_training(
        cfg, RUN_HP, {"advisor_noise": [0.0, 0.2]}, [0], out, eval_episodes=0,
        checkpoint_every=0, progress=False,
    )  # fmt: skip
    assert summary["status"] == "finished" and summary["episodes_completed"] == [2, 2]
    record = summary["advisor"]
    assert record["spec"] == "my_advisors:advisor" and record["kind"] == "function"
    assert len(record["source_sha256"]) == 64 and len(record["params_sha256"]) == 64
    metrics = np.load(out / "metrics.npz")
    assert np.all(metrics["outcome"] > 0)  # every episode played

    # The module's parameters change: the finished run is not resumed as if it were the same.
    example_module.write_text(example_module.read_text().replace('"reach": 0.5', '"reach": 0.4'))
    sys.modules.pop("my_advisors", None)
    with pytest.raises(ValueError, match="its advisor's parameters changed since it started"):
        run_training(cfg, RUN_HP, {"advisor_noise": [0.0, 0.2]}, [0], out, resume=True,
                     eval_episodes=0, checkpoint_every=0, progress=False)  # fmt: skip
    assert json.loads((out / "run.json").read_text())["status"] == "finished"


def test_the_readme_prints_the_same_example():
    """The README's own-advisor example is this file's, so the test above covers it too."""
    readme = (DOCS.parents[1] / "README.md").read_text()
    blocks = re.findall(r"```python\n(.*?)```", readme, flags=re.S)
    assert example_source() in blocks
