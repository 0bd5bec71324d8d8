"""experiments/bench_width_align.py: the padding it sets, its refusals, and a CPU smoke run."""

from __future__ import annotations

import json

import pytest

from advisor_jax.agent import gemm_layers
from tests.experiments.scripts import load_script


@pytest.fixture
def script(monkeypatch):
    monkeypatch.setattr(gemm_layers, "padded", gemm_layers.padded)  # restored after the test
    return load_script("bench_width_align")


def test_hidden_widths_take_the_alignment_and_the_inputs_keep_eight(script):
    assert script.critic_shapes("paper") == [[24, 1008], [1008, 504], [504, 608], [608, 1]]
    script.pad_widths_to(64)
    assert script.critic_shapes("paper") == [[24, 1024], [1024, 512], [512, 640], [640, 1]]
    script.pad_widths_to(32)
    assert script.critic_shapes("paper") == [[24, 1024], [1024, 512], [512, 608], [608, 1]]


def test_an_alignment_that_is_no_multiple_of_eight_is_refused(script):
    with pytest.raises(ValueError, match="--align 12 must be"):
        script.pad_widths_to(12)
    with pytest.raises(SystemExit):
        script.main(["--align", "8", "20"])


def test_a_cpu_run_writes_one_row_per_alignment(script, tmp_path):
    argv = ["--align", "64", "--preset", "quick", "--agents", "1", "--chunk", "20"]
    script.main([*argv, "--repeats", "1", "--precision", "fp32", "--out", str(tmp_path)])
    (row,) = json.loads((tmp_path / "bench_width_align.json").read_text())["rows"]
    assert row["align"] == 64 and row["critic_shapes"][1] == [192, 192]
    assert row["agent_steps_per_s"] > 0
    assert "| 1 | 64 | 192 → 192 → 192 |" in (tmp_path / "bench_width_align.md").read_text()
