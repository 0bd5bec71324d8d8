"""The matmul ceiling every learner report divides by (``bench.measure.matmul_ceiling``): a
chain of dependent products, each of which is computed."""

from __future__ import annotations

import jax
import numpy as np
import pytest

from advisor_jax.bench import measure
from tests.experiments.scripts import load_script


def test_the_chain_computes_every_product_in_turn():
    rng = np.random.default_rng(0)
    a = rng.normal(size=(16, 16)).astype(np.float32) / 4
    c = rng.normal(size=(16, 16)).astype(np.float32)
    with jax.default_matmul_precision("highest"):
        out = np.asarray(measure.chained_matmuls(a, c, 3))
    np.testing.assert_allclose(out, a @ (a @ (a @ c)), rtol=1e-4, atol=1e-5)


def test_the_ceiling_counts_the_flops_of_the_whole_chain(monkeypatch):
    # every call "takes" one second: the rate is then the FLOPs of one call
    monkeypatch.setattr(measure, "first_and_best", lambda fn, repeats: (fn(), 1.0))
    assert measure.matmul_ceiling(64, chain=3) == pytest.approx(2 * 64**3 * 3)
    assert measure.matmul_ceiling(64, chain=1, dtype="bfloat16") == pytest.approx(2 * 64**3)


def test_the_ceiling_study_times_both_ways_in_every_round(tmp_path):
    rows = load_script("bench_ceiling").main(["--size", "64", "--chain", "2", "--rounds", "2",
                               "--out", str(tmp_path / "c.json")])  # fmt: skip
    assert [(r["dtype"], r["round"]) for r in rows] == [
        ("bfloat16", 0),
        ("bfloat16", 1),
        ("float32", 0),
        ("float32", 1),
    ]
    assert all(r["one_product"] > 0 and r["chained"] > 0 for r in rows)
    assert all(0.1 < r["mag"] < 10 for r in rows)  # the chain kept its scale


def test_a_cpu_times_one_product_per_call_unless_told(monkeypatch):
    monkeypatch.setattr(measure, "first_and_best", lambda fn, repeats: (fn(), 1.0))
    assert jax.default_backend() == "cpu"
    assert measure.matmul_ceiling(64) == pytest.approx(2 * 64**3)
    assert measure.matmul_ceiling(64, chain=measure.CHAIN) == pytest.approx(2 * 64**3 * 20)
