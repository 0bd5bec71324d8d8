"""experiments/first_layer_kernel.py: parity and the compiled update, small, on the CPU."""

from __future__ import annotations

import json

from tests.experiments.scripts import load_script

first_layer_kernel = load_script("first_layer_kernel")


def test_a_small_run_reports_parity_and_no_kernel_launch_off_a_gpu(tmp_path):
    argv = ["--small", "--agents", "2", "--updates", "2", "--precision", "fp32"]
    assert first_layer_kernel.main([*argv, "--out", str(tmp_path)]) == 0
    (row,) = json.loads((tmp_path / "first_layer_kernel.json").read_text())["rows"]
    assert row["step_difference"] < 1e-3 * row["step_size"]
    assert row["update_difference"] < 1e-4
    assert row["kernel_calls"] == 0  # interpreted on a CPU: ordinary operations, no launch
    assert row["splits"] == 2 and row["entries"] == 24 * 72  # the small layer's 2 row tiles
    assert row["split_difference"] <= 1e-5 * row["gradient_scale"]
    assert "| fp32 |" in (tmp_path / "first_layer_kernel.md").read_text()


def test_the_mask_from_the_input_changes_no_entry_and_fp32_has_none():
    row = first_layer_kernel.from_input_check("bf16", small=True)
    assert row == dict(from_input_entries_differing=0, from_input_entries=5 * 24 * 72)
    assert first_layer_kernel.from_input_check("fp32")["from_input_entries"] is None
