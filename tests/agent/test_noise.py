"""Ornstein–Uhlenbeck noise: one step by hand, reset, mean reversion, stationary std."""

import jax
import jax.numpy as jnp
import numpy as np

from advisor_jax.agent.noise import OUState, ou_init, ou_reset, ou_step


def test_init_and_one_step_by_hand():
    state = ou_init((3, 2))
    assert state.x.shape == (3, 2) and float(jnp.abs(state.x).max()) == 0.0
    x0 = jnp.array([[1.0, -2.0]])
    key = jax.random.key(3)
    xi = np.asarray(jax.random.normal(key, (1, 2)))
    new, noise = ou_step(OUState(x0), key, 0.15, 0.2, mu=0.5)
    expected = np.array([[1.0, -2.0]]) + 0.15 * (0.5 - np.array([[1.0, -2.0]])) + 0.2 * xi
    np.testing.assert_allclose(new.x, expected, rtol=1e-6)
    np.testing.assert_array_equal(noise, new.x)


def test_reset_zeroes_only_done():
    state = OUState(jnp.array([[1.0, 2.0], [3.0, 4.0], [5.0, 6.0]]))
    out = ou_reset(state, jnp.array([True, False, True]))
    np.testing.assert_array_equal(out.x, [[0, 0], [3, 4], [0, 0]])
    out = ou_reset(state, jnp.array([0.0, 1.0, 0.0]))  # float flags work too
    np.testing.assert_array_equal(out.x, [[1, 2], [0, 0], [5, 6]])


def _run(x0, theta, sigma, steps, key):
    def body(state, k):
        state, noise = ou_step(state, k, theta, sigma)
        return state, noise

    _, xs = jax.lax.scan(body, OUState(x0), jax.random.split(key, steps))
    return np.asarray(xs)  # [steps, ...]


def test_mean_reversion_without_noise():
    xs = _run(jnp.array([1.0, -1.0]), 0.15, 0.0, 10, jax.random.key(0))
    np.testing.assert_allclose(xs[-1], np.array([1.0, -1.0]) * 0.85**10, rtol=1e-5)


def test_stationary_statistics():
    theta, sigma = 0.15, 0.2
    # 2000 independent chains × 2 dims, started at 3 and run far past the 1/θ ≈ 7 step
    # relaxation time: the mean must have reverted to 0 and the spread be stationary.
    xs = _run(jnp.full((2000, 2), 3.0), theta, sigma, 200, jax.random.key(1))
    final = xs[-1].ravel()  # 4000 independent draws from (nearly) the stationary law
    std_expected = sigma / np.sqrt(theta * (2.0 - theta))  # ≈ 0.3288
    assert abs(final.mean()) < 5 * std_expected / np.sqrt(final.size)
    # The std of a 4000-sample std estimate is ≈ std/sqrt(2·4000) ≈ 1.1 %; allow 5 %.
    assert abs(final.std() / std_expected - 1.0) < 0.05
    # The one-step autocorrelation of an AR(1) with coefficient 1 - θ.
    a, b = xs[-51:-1].ravel(), xs[-50:].ravel()
    assert abs(np.corrcoef(a, b)[0, 1] - (1.0 - theta)) < 0.02
