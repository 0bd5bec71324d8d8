"""Eq. (1) selector on every branch, its sampling statistics, and Eq. (11)."""

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from advisor_jax.agent.config import HParams
from advisor_jax.agent.selector import advisor_probability, expected_max_firing_rate, select_action

HP = HParams(eps_start=0.85, eps_decay=0.0015, advisor_episodes=250.0)


@pytest.mark.parametrize(
    "q_act, q_adv, episode, expected",
    [
        (1.0, 2.0, 10, 1.0),  # Q_act < Q_adv ⇒ 1
        (2.0, 2.0, 10, 1.0),  # equality is the ≤ branch ⇒ 1
        (3.0, 2.0, 0, 0.85),  # Q_act > Q_adv ⇒ ε_st - b·0
        (3.0, 2.0, 100, 0.85 - 0.15),  # ε_st - b·100 = 0.70
        (3.0, 2.0, 250, 0.85 - 0.375),  # N = N_T still uses the advisor: 0.475
        (1.0, 2.0, 250, 1.0),
        (1.0, 2.0, 251, 0.0),  # N > N_T ⇒ 0, whatever the Q-values
        (3.0, 2.0, 251, 0.0),
    ],
)
def test_eq1_branches(q_act, q_adv, episode, expected):
    eps = advisor_probability(jnp.float32(q_act), jnp.float32(q_adv), jnp.int32(episode), HP)
    assert float(eps) == pytest.approx(expected, abs=1e-6)


def test_eq1_clipping_both_ends():
    # The paper's b = 0.15 read per episode: ε_st - bN < 0 from N = 6 on ⇒ clipped to 0.
    hp = HParams(eps_start=0.85, eps_decay=0.15, advisor_episodes=250.0)
    assert float(advisor_probability(3.0, 2.0, 6, hp)) == 0.0
    assert float(advisor_probability(3.0, 2.0, 5, hp)) == pytest.approx(0.1, abs=1e-6)
    # ε_st > 1 from a sweep is clipped to 1.
    hp = HParams(eps_start=1.3, eps_decay=0.001, advisor_episodes=1000.0)
    assert float(advisor_probability(3.0, 2.0, 100, hp)) == 1.0
    assert float(advisor_probability(3.0, 2.0, 400, hp)) == pytest.approx(0.9, abs=1e-6)


def test_eq1_vectorised_branches():
    q_act = jnp.array([1.0, 3.0, 3.0, 1.0])
    q_adv = jnp.array([2.0, 2.0, 2.0, 2.0])
    episode = jnp.array([0, 0, 200, 300])
    eps = advisor_probability(q_act, q_adv, episode, HP)
    np.testing.assert_allclose(eps, [1.0, 0.85, 0.55, 0.0], atol=1e-6)


def test_select_action_statistics():
    n = 20_000
    q_act = jnp.full((n,), 3.0)
    q_adv = jnp.full((n,), 2.0)
    actor = jnp.broadcast_to(jnp.array([0.1, 0.2]), (n, 2))
    advisor = jnp.broadcast_to(jnp.array([0.9, -0.5]), (n, 2))
    select = jax.jit(select_action)
    action, used = select(jax.random.key(0), actor, advisor, q_act, q_adv, 100, HP)
    eps = 0.70
    rate = float(used.mean())
    # Binomial(n, ε): sd = sqrt(ε(1-ε)/n) ≈ 0.0032; 5 sd tolerance.
    assert abs(rate - eps) < 5 * np.sqrt(eps * (1 - eps) / n), rate
    action, used = np.asarray(action), np.asarray(used)
    np.testing.assert_array_equal(action[used], np.broadcast_to(advisor[0], (used.sum(), 2)))
    np.testing.assert_array_equal(action[~used], np.broadcast_to(actor[0], ((~used).sum(), 2)))
    # The deterministic ends: ε = 1 always advisor, ε = 0 never.
    _, used = select(jax.random.key(1), actor, advisor, q_act - 2.0, q_adv, 100, HP)
    assert bool(used.all())
    _, used = select(jax.random.key(2), actor, advisor, q_act - 2.0, q_adv, 251, HP)
    assert not bool(used.any())


def test_select_action_vmaps_over_hparams():
    hps = jax.tree.map(lambda x: jnp.full(3, x, jnp.float32), HParams())
    hps = hps.replace(eps_start=jnp.array([0.2, 0.5, 0.9]))
    n = 20_000
    keys = jax.random.split(jax.random.key(5), 3)
    actions = jnp.zeros((n, 2))

    def one(key, hp):
        return select_action(key, actions, actions + 1.0, jnp.ones(n), jnp.zeros(n), 0, hp)

    _, used = jax.vmap(one)(keys, hps)
    np.testing.assert_allclose(used.mean(axis=1), [0.2, 0.5, 0.9], atol=0.02)


@pytest.mark.parametrize("window", [1, 10, 30])
def test_eq11_against_moving_average(window):
    eps_start, b = 0.85, 0.0015
    episodes = np.arange(0, 300)
    upper = b * episodes + 1.0 - eps_start  # E(fr_ub) at every episode, Appendix D
    for n in range(window - 1, 300, 37):
        direct = upper[n - window + 1 : n + 1].mean()
        got = float(expected_max_firing_rate(n, eps_start, b, window))
        assert got == pytest.approx(direct, abs=1e-6), (n, window)
    # Vectorised over episodes and with traced arguments.
    got = jax.jit(expected_max_firing_rate)(jnp.arange(29, 40), eps_start, b, window)
    want = [upper[n - window + 1 : n + 1].mean() for n in range(29, 40)]
    np.testing.assert_allclose(got, want, atol=1e-6)
