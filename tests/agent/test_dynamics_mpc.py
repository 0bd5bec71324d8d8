"""The MCP + model-free building blocks (docs/baselines.md): dynamics model, random-shooting
MPC and Eq. 8 from observations. The behaviour-cloning step is agent/imitation.py's, tested in
tests/agent/test_imitation.py.

Small shapes throughout: a (64, 64) model, a (64, 64) actor, a few hundred env steps. What
each test would catch: a model that does not learn (or learns from rows past the valid
count), a rollout that is not the repeated one-step prediction, a planner that does not stop
scoring a candidate after its predicted goal or collision, a reward that drifts from the
env's, and inputs that should be refused.
"""

from __future__ import annotations

import contextlib
import io

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from advisor_jax.agent.dynamics_model import (
    make_dynamics_model,
    normalizer_from_data,
    observation_delta,
)
from advisor_jax.agent.mpc import (
    candidate_returns,
    make_mpc_policy,
    plan,
    sample_candidates,
)
from advisor_jax.agent.networks import count_params
from advisor_jax.agent.replay_buffer import Transition
from envs.reward import eq8_from_obs
from envs.state import EnvConfig

with contextlib.redirect_stdout(io.StringIO()):  # MJX's "Failed to import warp" notice
    import envs

CFG = EnvConfig()
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
    np.testing.assert_allclose(norm.delta_std, 0.01, rtol=1e-5)  # constant change: the floor
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


# -- Eq. 8 from observations ----------------------------------------------------------------


def _obs(p=1.0, d=2.0, delta=0.0):
    o = np.zeros(20, np.float32)
    o[:16], o[16], o[17] = p, delta, d
    return jnp.asarray(o)


def test_eq8_hand_cases():
    reward = lambda prev, obs: float(eq8_from_obs(prev, obs, CFG)[0])  # noqa: E731
    assert reward(_obs(0.8, 1.0), _obs(0.6, 0.9)) == pytest.approx(5 * 0.1 + 5 * -0.2, abs=1e-5)
    assert reward(_obs(0.8, 0.3), _obs(0.8, 0.15)) == 10.0  # d ≤ T_g
    assert reward(_obs(0.8, 1.0), _obs(0.1, 0.9)) == -10.0  # min P ≤ T_c
    assert reward(_obs(0.8, 0.3), _obs(0.05, 0.1)) == 10.0  # both: the goal wins
    # Predictions out of the contract's ranges are clipped: P ∈ [0, 1], d ≥ 0.
    assert reward(_obs(0.9, 1.0), _obs(1.7, 1.0)) == pytest.approx(5 * 0.1, abs=1e-5)
    _, goal, collision = eq8_from_obs(_obs(0.8, 0.5), _obs(-0.2, -0.3), CFG)
    assert bool(goal) and not bool(collision)


def test_eq8_matches_the_env_on_random_steps():
    """On 640 random-action steps of the training arena Eq. 8 from (s, s') equals the env's
    reward exactly, except on steps that only the footprint test ended (a collision with
    min P > T_c): there the env gives −c2 and the observation the shaping term."""
    env = envs.make_env("training")
    n_envs, n_steps = 16, 40

    def run(key):
        k_reset, k_act = jax.random.split(key)
        states = jax.vmap(env.reset)(jax.random.split(k_reset, n_envs))

        def body(states, k):
            actions = sample_candidates(k, n_envs, 1)[:, 0]
            new = jax.vmap(env.step)(states, actions)
            ours = eq8_from_obs(states.obs, new.terminal_obs, env.config)
            return new, (new.reward, new.outcome, new.terminal_obs, ours)

        return jax.lax.scan(body, states, jax.random.split(k_act, n_steps))[1]

    env_reward, outcome, next_obs, (reward, goal, collision) = jax.jit(run)(jax.random.PRNGKey(11))
    footprint_only = (outcome == envs.COLLISION) & (next_obs[..., :16].min(-1) > 0.1)
    same = ~footprint_only
    assert int(same.sum()) >= 600
    np.testing.assert_array_equal(np.asarray(reward)[same], np.asarray(env_reward)[same])
    np.testing.assert_array_equal(goal[same], (outcome == envs.GOAL)[same])
    np.testing.assert_array_equal(collision[same], (outcome == envs.COLLISION)[same])
    assert int((outcome == envs.COLLISION).sum()) >= 1  # the collision branch was exercised


# -- random-shooting MPC --------------------------------------------------------------------


def _hand_model(obs, action):
    """d shrinks by 0.2 V, every P by 0.75 ω (turning left closes in on a wall)."""
    d = obs[..., 17] - 0.2 * action[..., 0]
    p = obs[..., :16] - 0.75 * action[..., 1:2]
    return obs.at[..., 17].set(d).at[..., :16].set(p)


HAND = np.array(
    [
        [[0.5, -1.0], [0.5, -1.0], [0.5, -1.0]],  # best shaping: 1.5 + 0.5 + 0.5 = 2.5
        [[1.0, 1.0], [1.0, 0.0], [1.0, 0.0]],  # collides at step 1 (P 0.05): −10, then done
        [[1.0, 0.0], [1.0, 0.0], [0.0, 1.0]],  # goal at step 2 (d 0.1), "crash" at 3: 1 + 10
        [[0.0, 0.0], [0.0, 0.0], [0.0, 0.0]],  # stands still: 0
    ],
    np.float32,
)


def test_plan_picks_the_best_hand_made_candidate():
    start = _obs(p=0.8, d=0.5)
    returns = candidate_returns(_hand_model, start, jnp.asarray(HAND), CFG)
    np.testing.assert_allclose(returns, [2.5, -10.0, 11.0, 0.0], rtol=1e-5, atol=1e-5)
    action, _ = jax.jit(plan, static_argnums=(0, 3))(_hand_model, start, jnp.asarray(HAND), CFG)
    np.testing.assert_array_equal(action, HAND[2, 0])
    # Without the goal candidate, the best shaping wins; a NaN return ranks last.
    action, _ = plan(_hand_model, start, jnp.asarray(HAND[[1, 3, 0]]), CFG)
    np.testing.assert_array_equal(action, HAND[0, 0])
    nan_model = lambda s, a: jnp.where(a[0] > 0.9, jnp.nan, 1.0) * _hand_model(s, a)  # noqa: E731
    action, returns = plan(nan_model, start, jnp.asarray(HAND), CFG)
    assert np.isnan(returns[1]) and np.isnan(returns[2])
    np.testing.assert_array_equal(action, HAND[0, 0])


def test_sampled_candidates_fill_the_box():
    c = np.asarray(sample_candidates(jax.random.PRNGKey(12), 500, 20))
    assert c.shape == (500, 20, 2) and c.dtype == np.float32
    assert c[..., 0].min() >= 0.0 and c[..., 0].max() <= 1.0
    assert c[..., 1].min() >= -1.0 and c[..., 1].max() <= 1.0
    assert c[..., 0].min() < 0.01 and c[..., 0].max() > 0.99 and c[..., 1].min() < -0.98


def test_mpc_policy_vmaps_over_agents():
    """The neural-model policy, vmapped over two agents' models, equals each run alone."""
    model = make_dynamics_model((32,))
    policy = make_mpc_policy(model, 16, 3, CFG)
    keys = jax.random.split(jax.random.PRNGKey(13), 2)
    states = jax.vmap(model.init)(keys)
    obs = jnp.stack([_obs(0.7, 1.0, 0.3), _obs(0.5, 2.0, -1.0)])
    both = jax.jit(jax.vmap(policy))(states.params, states.norm, obs, keys)
    for i in range(2):
        one = jax.tree.map(lambda x, i=i: x[i], states)
        alone = policy(one.params, one.norm, obs[i], keys[i])
        np.testing.assert_allclose(both[i], alone, rtol=1e-6, atol=1e-6)
        assert 0.0 <= float(alone[0]) <= 1.0 and -1.0 <= float(alone[1]) <= 1.0


# -- bad input ------------------------------------------------------------------------------


@pytest.mark.parametrize(
    "k, h, message",
    [
        (0, 20, "mpc_candidates (K) must be a positive integer, got 0"),
        (1000, 0, "mpc_horizon (H) must be a positive integer, got 0"),
        (-3, 20, "got -3"),
        (True, 20, "got True"),
        (1000, 2.5, "got 2.5"),
    ],
)
def test_bad_mpc_sizes(k, h, message):
    with pytest.raises(ValueError, match=message.replace("(", r"\(").replace(")", r"\)")):
        sample_candidates(jax.random.PRNGKey(0), k, h)
    with pytest.raises(ValueError, match="must be a positive integer"):
        make_mpc_policy(make_dynamics_model((8,)), k, h, CFG)


def test_bad_candidates():
    with pytest.raises(ValueError, match=r"got 0"):
        plan(_hand_model, _obs(), jnp.zeros((0, 3, 2)), CFG)
    with pytest.raises(ValueError, match=r"shape \[K, H, 2\]"):
        plan(_hand_model, _obs(), jnp.zeros((4, 3)), CFG)


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
