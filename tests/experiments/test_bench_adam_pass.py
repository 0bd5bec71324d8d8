"""experiments/bench_adam_pass.py: its Adam pass is training's Adam, and its table is written."""

from __future__ import annotations

import json

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from advisor_jax.agent import adam
from tests.experiments.scripts import load_script


def test_the_timed_pass_is_the_update_training_applies():
    script = load_script("bench_adam_pass")
    grad, (count, mu, nu), matrix = script.operands(1, (8, 4))
    one = lambda x: x[0]  # noqa: E731
    matrix_new, mu_new, nu_new = script.passes(lr=1e-3)["adam"](
        one(grad), (one(count), one(mu), one(nu)), one(matrix)
    )
    optimizer = adam.adam(1e-3, mu_dtype=jnp.bfloat16, nu_bf16=True)
    state = optimizer.init(one(matrix))
    state = (state[0]._replace(count=one(count), mu=one(mu), nu=one(nu)), *state[1:])
    steps, state = optimizer.update(one(grad).astype(jnp.float32), state, one(matrix))
    expected = adam.apply_updates(one(matrix), steps, one(count))
    np.testing.assert_array_equal(np.asarray(matrix_new), np.asarray(expected))
    np.testing.assert_array_equal(np.asarray(mu_new), np.asarray(state[0].mu))
    np.testing.assert_array_equal(np.asarray(nu_new), np.asarray(state[0].nu))
    assert matrix_new.dtype == jnp.bfloat16 and not np.array_equal(matrix_new, one(matrix))


def test_the_norm_rows_are_the_squared_gradient_summed():
    script = load_script("bench_adam_pass")
    grad, state, matrix = script.operands(2, (6, 5))
    rows = jax.vmap(script.passes()["adam + norm rows"])(grad, state, matrix)[-1]
    g = np.asarray(grad.astype(jnp.float32))
    np.testing.assert_allclose(np.asarray(rows), np.sum(g**2, axis=(1, 2, 3)), rtol=1e-5)


def test_the_benchmark_writes_one_row_per_pass(tmp_path):
    script = load_script("bench_adam_pass")
    script.main(["--agents", "1", "2", "--shape", "8", "4", "--repeats", "1", "--calls", "1",
                 "--out", str(tmp_path)])  # fmt: skip
    rows = json.loads((tmp_path / "bench_adam_pass.json").read_text())["rows"]
    assert [(r["agents"], r["variant"]) for r in rows] == [
        (n, v) for n in (1, 2) for v in ("adam", "adam + norm rows")
    ]
    assert all(r["bytes"] == 7 * 2 * r["agents"] * 2 * 8 * 4 for r in rows)
    for r in rows:  # the share of a copy's bandwidth is the two rates' ratio
        assert r["pct_copy"] == pytest.approx(100 * r["gb_per_s"] / r["copy_gb_per_s"])
    assert "| 2 | 8×4 | adam + norm rows |" in (tmp_path / "bench_adam_pass.md").read_text()
