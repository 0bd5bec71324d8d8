"""The MCP + model-free building blocks (docs/baselines.md): dynamics model, random-shooting
MPC, Eq. 8 from observations and the imitation step.

Small shapes throughout: a (64, 64) model, a (64, 64) actor, a few hundred env steps. What
each test would catch: a model that does not learn (or learns from rows past the valid
count), a rollout that is not the repeated one-step prediction, a planner that does not stop
scoring a candidate after its predicted goal or collision, a reward that drifts from the
env's, and inputs that should be refused.
"""

from __future__ import annotations

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from advisor_jax.agent.dynamics_model import (
    make_dynamics_model,
    normalizer_from_data,
    observation_delta,
)
from advisor_jax.agent.networks import count_params
from advisor_jax.agent.replay_buffer import Transition

SMALL = (64, 64)
PAD = 904  # rows past the valid count, filled with garbage: must never be read


def _data(obs, action, next_obs, pad=PAD) -> Transition:
    """A replay-like Transition whose rows past len(obs) hold huge values."""
    n = len(obs)

    def padded(x):
        return np.concatenate([x, np.full((pad, x.shape[1]), 1e3, np.float32)]).astype(np.float32)

    return Transition(
        obs=padded(obs),
        action=padded(action),
        advisor_action=padded(action),
        reward=np.zeros(n + pad, np.float32),
        next_obs=padded(next_obs),
        terminal=np.zeros(n + pad, np.float32),
    )


def _random_actions(rng, shape):
    return np.stack([rng.uniform(0.0, 1.0, shape), rng.uniform(-1.0, 1.0, shape)], axis=-1).astype(
        np.float32
    )


@pytest.fixture(scope="module")
def small_model():
    model = make_dynamics_model(SMALL)
    fit = jax.jit(model.fit, static_argnames=("steps", "batch_size"))
    return model, fit


# -- the dynamics model ---------------------------------------------------------------------


def test_paper_size_parameter_count():
    model = make_dynamics_model()
    shapes = jax.eval_shape(model.init, jax.random.PRNGKey(0)).params
    assert count_params(shapes) == 22 * 500 + 500 + 500 * 500 + 500 + 500 * 20 + 20  # 272,020


def test_fits_a_linear_system(small_model):
    """s' = A s + B a, A = 0.95 I + 0.01 R: held-out one-step MSE < 1 % of Var(Δs) (the
    unfitted model is far above), 10-step open-loop error below the zero-change predictor's."""
    model, fit = small_model
    rng = np.random.default_rng(0)
    a_mat = 0.95 * np.eye(20) + 0.01 * rng.normal(size=(20, 20))
    b_mat = 0.1 * rng.normal(size=(20, 2))

    def step(s, a):
        return (s @ a_mat.T + a @ b_mat.T).astype(np.float32)

    obs = rng.uniform(-1.0, 1.0, (5120, 20)).astype(np.float32)
    act = _random_actions(rng, (5120,))
    nxt = step(obs, act)
    train, test = slice(0, 4096), slice(4096, None)
    data = _data(obs[train], act[train], nxt[train])
    norm = normalizer_from_data(data, 4096)
    state = model.init(jax.random.PRNGKey(1)).replace(norm=norm)

    var_delta = float(np.mean(np.var(nxt[test] - obs[test], axis=0)))

    def one_step_mse(params):
        pred = model.predict(params, norm, obs[test], act[test])
        return float(jnp.mean(jnp.square(pred - nxt[test])))

    assert one_step_mse(state.params) > 0.1 * var_delta  # the bound can fail
    state, losses = fit(state, data, 4096, jax.random.PRNGKey(2), 1e-3, 0.01, 2000, 512)
    assert np.all(np.isfinite(losses)) and losses[-100:].mean() < 0.1 * losses[:10].mean()
    assert one_step_mse(state.params) < 0.01 * var_delta

    starts = rng.uniform(-1.0, 1.0, (64, 20)).astype(np.float32)
    actions = _random_actions(rng, (64, 10))
    truth = starts
    for k in range(10):
        truth = step(truth, actions[:, k])
    pred = jax.vmap(model.rollout, in_axes=(None, None, 0, 0))(state.params, norm, starts, actions)
    model_err = float(np.mean(np.square(pred[:, -1] - truth)))
    zero_err = float(np.mean(np.square(starts - truth)))
    assert model_err < 0.1 * zero_err


def test_goal_angle_wraps(small_model):
    """δ' = wrap(δ + 0.5 ω): the model learns the wrapped change, so pairs that cross ±π are
    predicted within 0.05 rad on average (0.15 at worst), as well as the others, and the
    prediction stays in [−π, π)."""
    model, fit = small_model
    rng = np.random.default_rng(3)
    obs = rng.uniform(0.0, 1.0, (5120, 20)).astype(np.float32)
    obs[:, 16] = rng.uniform(-np.pi, np.pi, 5120)
    act = _random_actions(rng, (5120,))
    nxt = obs.copy()
    nxt[:, 16] = (obs[:, 16] + 0.5 * act[:, 1] + np.pi) % (2 * np.pi) - np.pi
    data = _data(obs[:4096], act[:4096], nxt[:4096])
    norm = normalizer_from_data(data, 4096)
    assert float(norm.delta_std[16]) < 0.5  # wrapped changes: no 2π jumps in the statistics
    state = model.init(jax.random.PRNGKey(4)).replace(norm=norm)
    state, _ = fit(state, data, 4096, jax.random.PRNGKey(5), 1e-3, 0.01, 2000, 512)
    test = slice(4096, None)
    crossing = np.abs(obs[test, 16] + 0.5 * act[test, 1]) >= np.pi
    assert crossing.sum() >= 10
    pred = np.asarray(model.predict(state.params, norm, obs[test], act[test]))[:, 16]
    error = (pred - nxt[test, 16] + np.pi) % (2 * np.pi) - np.pi
    # An unwrapped model would be off by ~2π there; a fitted one is as good as elsewhere.
    error = np.abs(error)
    assert error[crossing].mean() < 0.05 and error[crossing].max() < 0.15
    assert error[crossing].mean() < 2.0 * error[~crossing].mean()
    assert np.all((pred >= -np.pi) & (pred < np.pi))


def test_rollout_is_repeated_one_step():
    model = make_dynamics_model((32,))
    rng = np.random.default_rng(6)
    obs = rng.uniform(0.0, 1.0, (200, 20)).astype(np.float32)
    act = _random_actions(rng, (200,))
    nxt = obs + 0.1 * rng.normal(size=obs.shape).astype(np.float32)
    norm = normalizer_from_data(_data(obs, act, nxt, pad=0), 200)
    params = model.init(jax.random.PRNGKey(7)).params
    actions = _random_actions(rng, (7,))
    rolled = model.rollout(params, norm, obs[0], actions)
    s, stepped = obs[0], []
    for a in actions:
        s = model.predict(params, norm, s, a)
        stepped.append(s)
    np.testing.assert_allclose(rolled, np.stack(stepped), rtol=1e-6, atol=1e-6)


def test_normalizer_reads_only_valid_rows():
    rng = np.random.default_rng(8)
    obs = rng.normal(size=(50, 20)).astype(np.float32)
    act = _random_actions(rng, (50,))
    nxt = obs + 0.3
    norm = normalizer_from_data(_data(obs, act, nxt), 50)
    np.testing.assert_allclose(norm.obs_mean, obs.mean(0), atol=1e-5)
    np.testing.assert_allclose(norm.obs_std, obs.std(0), rtol=1e-4)
    np.testing.assert_allclose(norm.action_mean, act.mean(0), atol=1e-5)
    np.testing.assert_allclose(norm.delta_mean, 0.3, atol=1e-5)
    np.testing.assert_allclose(norm.delta_std, 1e-6, atol=2e-6)  # constant change: the floor
    np.testing.assert_allclose(observation_delta(obs, nxt)[:, :16], 0.3, atol=1e-5)


def test_fit_vmaps_over_agents(small_model):
    """Two agents' fits, vmapped, equal the same fits run alone."""
    model, fit = small_model
    rng = np.random.default_rng(9)
    obs = rng.uniform(0.0, 1.0, (256, 20)).astype(np.float32)
    act = _random_actions(rng, (256,))
    data = _data(obs, act, obs * 0.9, pad=0)
    norm = normalizer_from_data(data, 256)
    keys = jax.random.split(jax.random.PRNGKey(10), 2)
    states = jax.vmap(model.init)(keys).replace(
        norm=jax.tree.map(lambda x: jnp.stack([x] * 2), norm)
    )
    lrs = jnp.array([1e-3, 3e-4])
    both = jax.vmap(
        lambda s, k, lr: fit(s, data, 256, k, lr, 0.01, 5, 64)
    )(states, keys, lrs)  # fmt: skip
    for i in range(2):
        one = jax.tree.map(lambda x, i=i: x[i], states)
        alone = fit(one, data, 256, keys[i], lrs[i], 0.01, 5, 64)
        mine = jax.tree.map(lambda x, i=i: x[i], both)
        jax.tree.map(
            lambda a, b: np.testing.assert_allclose(a, b, rtol=1e-5, atol=1e-6), mine, alone
        )


# -- bad input ------------------------------------------------------------------------------


def test_bad_model_settings():
    with pytest.raises(ValueError, match=r"at least one layer, got \(\)"):
        make_dynamics_model(())
    with pytest.raises(ValueError, match="hidden width must be a positive integer, got 0"):
        make_dynamics_model((64, 0))
    model = make_dynamics_model((8,))
    state = model.init(jax.random.PRNGKey(0))
    zeros = np.zeros((4, 20), np.float32)
    data = _data(zeros, np.zeros((4, 2), np.float32), zeros)
    with pytest.raises(ValueError, match="model steps must be a positive integer, got 0"):
        model.fit(state, data, 4, jax.random.PRNGKey(0), 1e-3, 0.0, 0, 8)
    with pytest.raises(ValueError, match="model batch_size must be a positive integer, got -1"):
        model.fit(state, data, 4, jax.random.PRNGKey(0), 1e-3, 0.0, 3, -1)
