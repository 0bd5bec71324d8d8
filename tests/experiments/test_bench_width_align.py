"""experiments/bench_width_align.py: the padding it sets, its refusals, and a CPU smoke run."""

from __future__ import annotations

import json

import pytest

from advisor_jax.training import program
from tests.experiments.scripts import load_script


@pytest.fixture
def script(monkeypatch):
    monkeypatch.setattr(program, "program_layout", program.program_layout)  # restored after
    return load_script("bench_width_align")


def test_hidden_widths_take_the_alignment_and_the_inputs_keep_eight(script):
    assert script.critic_shapes("paper", 8) == [[24, 1008], [1008, 504], [504, 608], [608, 1]]
    assert script.critic_shapes("paper", 32) == [[24, 1024], [1024, 512], [512, 608], [608, 1]]
    # at 64 only widths of 512 and more: 501 columns stay at 504, not 512 (an eighth at most)
    assert script.critic_shapes("paper", 64) == [[24, 1024], [1024, 504], [504, 640], [640, 1]]


def test_the_alignment_reaches_every_programs_layout(script):
    script.pad_widths_to(64)
    for name in program.PROGRAMS:
        assert program.program_layout(name, "bf16", "gpu", 64).hidden_align == 64


def test_an_alignment_that_is_no_multiple_of_eight_is_refused(script):
    with pytest.raises(ValueError, match="--align 12 must be"):
        script.pad_widths_to(12)
    with pytest.raises(SystemExit):
        script.main(["--align", "8", "20"])


def test_a_cpu_run_writes_one_row_per_alignment(script, tmp_path):
    argv = ["--align", "16", "--preset", "quick", "--agents", "1", "--chunk", "20"]
    script.main([*argv, "--repeats", "1", "--precision", "fp32", "--out", str(tmp_path)])
    (row,) = json.loads((tmp_path / "bench_width_align.json").read_text())["rows"]
    assert row["align"] == 16 and row["critic_shapes"][1] == [144, 144]
    assert row["agent_steps_per_s"] > 0
    assert "| 1 | 16 | 144 → 144 → 144 |" in (tmp_path / "bench_width_align.md").read_text()
