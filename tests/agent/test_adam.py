"""The learners' Adam (``agent/adam.py``): v stored in bf16 by stochastic rounding.

The checks: the rounding gives one of the two bf16 neighbours and is exact on average; the
random bits are uniform and equal for ±x; off, the transformation is optax's; on, its first
step is optax's bit for bit and, over thousands of steps, its stored v follows the fp32 v
that optax keeps, where rounding to nearest leaves v where it started.
"""

from __future__ import annotations

import jax
import jax.numpy as jnp
import numpy as np
import optax
import pytest

from advisor_jax.agent import adam


def _neighbours(x: float) -> tuple[float, float]:
    down = float(jnp.asarray(x, jnp.float32).astype(jnp.bfloat16))
    if down > x:
        down = float(jnp.nextafter(jnp.bfloat16(down), jnp.bfloat16(-np.inf)))
    up = float(jnp.nextafter(jnp.bfloat16(down), jnp.bfloat16(np.inf)))
    return down, up


@pytest.mark.parametrize("x", [1.0 + 3 / 1024, 0.3721, 7.5e-7, 1234.567])
def test_stochastic_rounding_picks_a_neighbour_and_is_exact_on_average(x):
    bits = jnp.arange(0, 2**16, dtype=jnp.uint32)  # every draw once: the exact expectation
    rounded = adam.stochastic_bf16(jnp.full(bits.shape, x, jnp.float32), bits)
    assert rounded.dtype == jnp.bfloat16
    values = np.asarray(rounded.astype(jnp.float32), np.float64)
    down, up = _neighbours(np.float32(x))
    assert set(np.unique(values)) <= {down, up}
    # over all 2¹⁶ draws the mean is x up to the 2⁻¹⁶ of a bf16 step that the draws resolve
    assert abs(values.mean() - np.float32(x)) <= (up - down) * 2**-15


def test_exact_values_zero_and_non_finite_values_stay_as_they_are():
    x = jnp.asarray([0.0, 1.0, -2.5, 2.0**-126, np.inf, -np.inf, np.nan], jnp.float32)
    for draw in (0, 1, 2**15, 2**16 - 1):
        rounded = adam.stochastic_bf16(x, jnp.full(x.shape, draw, jnp.uint32))
        np.testing.assert_array_equal(np.asarray(rounded.astype(jnp.float32)), np.asarray(x))


def test_the_random_bits_are_uniform_and_equal_for_opposite_parameters():
    params = jax.random.normal(jax.random.key(0), (1 << 16,)) * 0.05
    bits = np.asarray(adam.dither(params))
    np.testing.assert_array_equal(bits, np.asarray(adam.dither(-params)))
    assert bits.min() >= 0 and bits.max() < 2**16
    counts = np.bincount(bits >> 12, minlength=16)  # 16 bins of 4,096 expected entries
    assert np.all(np.abs(counts - 4096) < 6 * 64)  # six standard deviations
    # Adam's steps, thousands of units in the last place and 0.1 % apart from entry to
    # entry, give unrelated bits (one step the same for all would shift all the draws alike)
    steps = 1e-4 * (1.0 + 1e-3 * jax.random.normal(jax.random.key(1), params.shape))
    moved = np.asarray(adam.dither(params - steps))
    assert abs(np.corrcoef(bits, moved)[0, 1]) < 0.02


def test_off_it_is_optax_adam():
    params = {"w": jnp.ones((3, 2)), "b": jnp.zeros(2)}
    grads = jax.tree.map(lambda p: p * 0.3 + 0.1, params)
    for mu_dtype in (None, jnp.bfloat16):
        ours, theirs = adam.adam(1e-3, mu_dtype), optax.adam(1e-3, mu_dtype=mu_dtype)
        a = ours.update(grads, ours.init(params), params)
        b = theirs.update(grads, theirs.init(params), params)
        for x, y in zip(jax.tree.leaves(a), jax.tree.leaves(b), strict=True):
            np.testing.assert_array_equal(np.asarray(x), np.asarray(y))


def _track(steps: int):
    """v after ``steps`` Adam steps of noisy gradients, stored in bf16; and optax's fp32 v on
    the same gradients and parameters."""
    params = {"w": jax.random.normal(jax.random.key(0), (4096,)) * 0.05}
    ours = adam.scale_by_adam(mu_dtype=jnp.bfloat16, nu_bf16=True)
    fp32 = optax.scale_by_adam(mu_dtype=jnp.bfloat16)

    def step(carry, key):
        p, s, s_fp32 = carry
        g = {"w": 1e-2 * (1.0 + 0.3 * jax.random.normal(key, (4096,)))}
        u, s = ours.update(g, s, p)
        s_fp32 = fp32.update(g, s_fp32, p)[1]
        return (jax.tree.map(lambda a, b: a - 1e-3 * b, p, u), s, s_fp32), None

    keys = jax.random.split(jax.random.key(1), steps)
    (_, s, s_fp32), _ = jax.lax.scan(step, (params, ours.init(params), fp32.init(params)), keys)
    return s.nu["w"], s_fp32.nu["w"]


def test_the_stored_v_follows_the_fp32_v():
    nu, nu_fp32 = _track(steps=3000)
    assert nu.dtype == jnp.bfloat16 and nu_fp32.dtype == jnp.float32
    ratio = np.asarray(nu.astype(jnp.float32) / nu_fp32, np.float64)
    # exact on average; each entry within a few percent (the rounding's noise, averaged by
    # the moving average over its ~1,000-step memory: about 2⁻⁹ · √(1000 / 2))
    assert abs(ratio.mean() - 1.0) < 0.005
    assert np.mean(np.abs(ratio - 1.0)) < 0.06


def test_rounded_to_nearest_v_would_not_move():
    # the reason for the stochastic rounding: v starting at 1 with g² = 0.5 decays towards
    # 0.5 in fp32, but b2 · v + (1 - b2) g² rounds back to 1 in bf16, step after step
    v = jnp.ones((), jnp.bfloat16)
    for _ in range(100):
        v = (0.999 * v.astype(jnp.float32) + 0.001 * 0.5).astype(jnp.bfloat16)
    assert float(v) == 1.0


def test_the_first_step_is_optax_adams_bit_for_bit():
    params = {"w": jax.random.normal(jax.random.key(2), (64, 8))}
    grads = {"w": jax.random.normal(jax.random.key(3), (64, 8))}
    ours = adam.adam(1e-3, jnp.bfloat16, nu_bf16=True)
    theirs = optax.adam(1e-3, mu_dtype=jnp.bfloat16)
    steps, state = ours.update(grads, ours.init(params), params)
    want, want_state = theirs.update(grads, theirs.init(params), params)
    np.testing.assert_array_equal(np.asarray(steps["w"]), np.asarray(want["w"]))
    np.testing.assert_array_equal(np.asarray(state[0].mu["w"]), np.asarray(want_state[0].mu["w"]))
    assert state[0].nu["w"].dtype == jnp.bfloat16
    assert jax.tree.structure(state) == jax.tree.structure(want_state)


def test_it_needs_the_parameters():
    tx = adam.adam(1e-3, nu_bf16=True)
    params = {"w": jnp.ones(3)}
    with pytest.raises(ValueError, match="needs the parameters"):
        tx.update(params, tx.init(params))


def test_the_stored_moments_pass_a_barrier():
    # without it XLA recomputed a steady block's earlier moments from every earlier gradient
    # inside the later passes (results/bench_bf16_second_moment/): the stored moments are what
    # leaves the barrier
    tx = adam.scale_by_adam(mu_dtype=jnp.bfloat16, nu_bf16=True)
    params = {"w": jnp.ones((4, 3))}
    jaxpr = jax.make_jaxpr(lambda g, s, p: tx.update(g, s, p)[1])(params, tx.init(params), params)
    (barrier,) = [e for e in jaxpr.eqns if e.primitive.name == "optimization_barrier"]
    assert [v.aval.dtype for v in barrier.outvars] == [jnp.bfloat16, jnp.bfloat16]
    assert set(barrier.outvars) <= set(jaxpr.jaxpr.outvars)
