"""experiments/bench_wgrad_adam.py: its epilogue is training's Adam step, and its fused kernel
computes the reference's outputs (Pallas's interpreter on the CPU)."""

from __future__ import annotations

import jax.numpy as jnp
import numpy as np

from advisor_jax.agent import adam
from tests.experiments.scripts import load_script


def test_the_epilogue_is_the_step_training_applies():
    script = load_script("bench_wgrad_adam")
    _, _, p, mu, nu, _, lr = script.operands(1, 4, 16, 8)
    p, mu, nu = p[0], mu[0], nu[0]
    g = jnp.linspace(-1e-3, 2e-3, p.size, dtype=jnp.float32).reshape(p.shape)
    optimizer = adam.adam(lr, mu_dtype=jnp.bfloat16, nu_bf16=True)
    state = optimizer.init(p)
    state = (state[0]._replace(count=jnp.int32(6), mu=mu, nu=nu), *state[1:])
    steps, state = optimizer.update(g, state, p)
    expected = adam.apply_updates(p, steps, jnp.int32(7))
    got = script.epilogue(g, p, mu, nu, jnp.int32(7), lr)
    for a, b in zip(got, (expected, state[0].mu, state[0].nu), strict=True):
        np.testing.assert_array_equal(np.asarray(a), np.asarray(b))
    assert not np.array_equal(np.asarray(got[0]), np.asarray(p))


def test_the_fused_kernel_matches_the_reference(tmp_path):
    script = load_script("bench_wgrad_adam")
    result = script.main(["--out", str(tmp_path)])
    check = result["check_small"]
    # Off by a bf16 unit of the largest entry at most: the stochastic rounding's hash turns an
    # fp32 difference of one unit (the interpreter's arithmetic against XLA's) into a rounding
    # the other way, so the matrix, rounded so, is equal in most entries, not all.
    for name in ("matrix", "m", "v"):
        assert check[name]["max_abs"] <= 2**-7 * check[name]["scale"], (name, check[name])
        assert check[name]["equal"] > 0.5, (name, check[name])
    assert check["norm rows"]["max_abs"] <= 1e-5 * check["norm rows"]["scale"]
    assert "A weight gradient with Adam" in (tmp_path / "bench_wgrad_adam.md").read_text()
