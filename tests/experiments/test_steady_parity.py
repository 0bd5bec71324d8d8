"""experiments/steady_parity.py: its bit-for-bit comparison and the program it builds with
XLA's multi-output fusion (GPU runs only; the CPU has no such option)."""

from __future__ import annotations

import jax
import numpy as np

from advisor_jax.agent.config import preset
from advisor_jax.training import compiler, program
from advisor_jax.training.devices import place
from tests.experiments.scripts import load_script

parity = load_script("steady_parity")


def test_bits_equal_tells_one_bit_and_the_sign_of_zero():
    a = {"w": np.array([1.0, np.nan, 0.0], np.float32), "n": np.array([3], np.int32)}
    assert parity.bits_equal(a, {"w": a["w"].copy(), "n": np.array([3], np.int32)})
    up = np.nextafter(np.float32(1.0), np.float32(2.0))
    assert not parity.bits_equal(a, {"w": np.array([up, np.nan, 0.0], np.float32), "n": a["n"]})
    assert not parity.bits_equal(a, {"w": np.array([1.0, np.nan, -0.0], np.float32), "n": a["n"]})
    assert not parity.bits_equal(a, {"w": a["w"], "n": np.array([3], np.int64)})


def test_fused_program_only_where_training_separates_outputs(monkeypatch):
    cfg, _ = preset("quick", "ATD3+AfDP", precision="bf16")
    assert parity.fused_program(cfg, place(1, 1), "latency-bound") is None  # CPU: no option

    seen = []
    real = program.compiler_options

    def spy(*args, **kwargs):
        seen.append((kwargs.get("separate"), dict(compiler.SEPARATE_OUTPUTS)))
        return real(*args, **kwargs)

    monkeypatch.setattr(jax, "default_backend", lambda: "gpu")
    monkeypatch.setattr(program, "compiler_options", spy)
    assert parity.fused_program(cfg, place(3, 1), "latency-bound") is None  # 3 agents: fused
    assert parity.fused_program(cfg, place(1, 1), "latency-bound") is not None
    assert seen == [(True, {})]  # built as training builds it, with the fusion left on
    assert compiler.SEPARATE_OUTPUTS == {"xla_disable_hlo_passes": "multi_output_fusion"}
