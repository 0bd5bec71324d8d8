"""experiments/held_targets.py: the parity check and the chunk's memory, small, on the CPU.
Two updates: the first with the actor step and its soft update (delay 4), the second after."""

from __future__ import annotations

import json

from tests.experiments.scripts import load_script

held_targets = load_script("held_targets")


def test_a_small_run_reports_parity_and_the_memory_the_hold_takes(tmp_path):
    argv = ["--small", "--agents", "2", "--chunk", "8", "--updates", "2", "--precision", "bf16"]
    assert held_targets.main([*argv, "--out", str(tmp_path)]) == 0
    (row,) = json.loads((tmp_path / "held_targets.json").read_text())["rows"]
    # Bit for bit under XLA's defaults; the suite's CPU emitters may round one element apart.
    assert isinstance(row["bit_for_bit"], bool) and row["max_abs_difference"] < 1e-5
    memory = row["temp_mib_per_agent"]
    assert memory["held"] > memory["built"]  # the held matrices live through the chunk
    assert "| bf16 |" in (tmp_path / "held_targets.md").read_text()


def test_the_held_critics_agree_to_rounding(tmp_path):
    argv = ["--small", "--agents", "2", "--chunk", "8", "--updates", "2", "--precision", "fp32"]
    assert held_targets.main([*argv, "--critics", "--out", str(tmp_path)]) == 0
    (row,) = json.loads((tmp_path / "held_targets.json").read_text())["rows"]
    assert row["max_abs_difference"] < 1e-5  # another summation order at most, not another rule
    assert set(row["temp_mib_per_agent"]) == {"held", "built"}
    assert "the critics and targets" in (tmp_path / "held_targets.md").read_text()
