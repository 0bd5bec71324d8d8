"""The pure update rules of learner.py on hand-made batches and a hand-made critic.

The hand-made critic is Q(s, a) = -||a - c(s)||² with c(s) = s[:2], so ∇_a Q = -2 (a - c)
and every expected number below is worked out by hand in the comments.
"""

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from advisor_jax.agent.update_rules import (
    addpg_actor_targets,
    bounded_targets,
    clip_action,
    critic_losses,
    critic_targets,
    dpg_actor_loss,
    mse_actor_loss,
    smoothed_target_actions,
    soft_update,
)


def quadratic_q(obs, action):
    return -jnp.sum(jnp.square(action - obs[..., :2]), axis=-1)


# Four samples: centre c = obs[:2], actor action a, advisor action a_adv.
CENTRES = jnp.array([[0.5, 0.0], [0.5, 0.0], [0.0, 0.5], [1.0, -1.0]])
OBS = jnp.concatenate([CENTRES, jnp.zeros((4, 18))], axis=1)
ACTIONS = jnp.array([[0.3, 0.2], [0.5, 0.1], [0.0, 0.5], [0.0, 0.0]])
ADVISOR = jnp.array([[0.5, 0.1], [0.2, -0.5], [0.0, 0.5], [0.9, -0.6]])
BETA = 0.1
# â = a + β·(-2)(a - c):
#   0: a - c = (-0.2, 0.2) → â = (0.34, 0.16), Q(â) = -0.0512; Q(a_adv) = -0.01 > ⇒ replaced
#   1: a - c = (0, 0.1)    → â = (0.5, 0.08),  Q(â) = -0.0064; Q(a_adv) = -0.34    ⇒ kept
#   2: a - c = 0           → â = a, Q(â) = 0 = Q(a_adv): not strictly greater  ⇒ kept
#   3: a - c = (-1, 1)     → â = (0.2, -0.2),  Q(â) = -1.28;   Q(a_adv) = -0.17 > ⇒ replaced
A_HAT_ADDPG = [[0.34, 0.16], [0.5, 0.08], [0.0, 0.5], [0.2, -0.2]]
A_HAT_AFP = [[0.5, 0.1], [0.5, 0.08], [0.0, 0.5], [0.9, -0.6]]


def test_addpg_targets_without_advisor():
    a_hat, replaced, *_ = addpg_actor_targets(quadratic_q, OBS, ACTIONS, ADVISOR, BETA, False)
    np.testing.assert_allclose(a_hat, A_HAT_ADDPG, atol=1e-6)
    assert replaced.dtype == jnp.bool_ and not bool(replaced.any())


def test_afp_replacement_mask():
    a_hat, replaced, *_ = jax.jit(addpg_actor_targets, static_argnums=(0, 5))(
        quadratic_q, OBS, ACTIONS, ADVISOR, BETA, True
    )
    np.testing.assert_array_equal(replaced, [True, False, False, True])
    np.testing.assert_allclose(a_hat, A_HAT_AFP, atol=1e-6)


def test_afp_replacement_can_be_switched_off():
    """N_P (advisor_policy_episodes): a traced False gives plain ADDPG targets."""
    targets = jax.jit(addpg_actor_targets, static_argnums=(0, 5))
    for allowed, a_hat_expected in ((True, A_HAT_AFP), (False, A_HAT_ADDPG)):
        a_hat, replaced, *_ = targets(
            quadratic_q, OBS, ACTIONS, ADVISOR, BETA, True, replace_allowed=jnp.asarray(allowed)
        )
        assert bool(replaced.any()) == allowed
        np.testing.assert_allclose(a_hat, a_hat_expected, atol=1e-6)


def test_addpg_actor_loss_and_gradient():
    a_hat, *_ = addpg_actor_targets(quadratic_q, OBS, ACTIONS, ADVISOR, BETA, True)
    # ||â - a||² per sample: 0.2² + 0.1² = 0.05; 0.02² = 0.0004; 0; 0.9² + 0.6² = 1.17.
    loss = mse_actor_loss(ACTIONS, a_hat)
    assert float(loss) == pytest.approx((0.05 + 0.0004 + 0.0 + 1.17) / 4, abs=1e-6)
    # d/da of (1/n) Σ ||â - a||² with â held fixed is 2 (a - â) / n.
    grad = jax.grad(mse_actor_loss)(ACTIONS, a_hat)
    np.testing.assert_allclose(grad, 2.0 * (ACTIONS - jnp.array(A_HAT_AFP)) / 4, atol=1e-6)

    # The target is stop-gradient'ed: with â = f(a) = a + 1, the loss is 2 per sample and
    # the gradient is -2/n per entry (it would be 0 if gradients flowed through â).
    def loss_of_a(a):
        return mse_actor_loss(a, a + 1.0)

    assert float(loss_of_a(ACTIONS)) == pytest.approx(2.0)
    np.testing.assert_allclose(jax.grad(loss_of_a)(ACTIONS), -0.5 * np.ones((4, 2)))


def test_addpg_target_ignores_gradient_through_actions():
    # The actor's actions enter Eq. (2) as data: no gradient w.r.t. them through â.
    def total(a):
        a_hat, *_ = addpg_actor_targets(quadratic_q, OBS, a, ADVISOR, BETA, True)
        return jnp.sum(a_hat)

    np.testing.assert_array_equal(jax.grad(total)(ACTIONS), np.zeros((4, 2)))


def test_dpg_loss():
    # Q(s, a) per sample: -0.08, -0.01, 0, -2 ⇒ loss = 2.09 / 4.
    assert float(dpg_actor_loss(quadratic_q, OBS, ACTIONS)) == pytest.approx(0.5225, abs=1e-6)
    # -(1/n) ∇_a Q = 2 (a - c) / n.
    grad = jax.grad(lambda a: dpg_actor_loss(quadratic_q, OBS, a))(ACTIONS)
    np.testing.assert_allclose(grad, 2.0 * (ACTIONS - CENTRES) / 4, atol=1e-6)


def test_critic_targets_twin_single_and_terminal():
    reward = jnp.array([1.0, -2.0, 0.5])
    terminal = jnp.array([0.0, 1.0, 0.0])
    twin = jnp.array([[3.0, 5.0, -1.0], [2.0, 7.0, 4.0]])
    # min = (2, 5, -1): 1 + 0.9·2 = 2.8; terminal ⇒ -2; 0.5 + 0.9·(-1) = -0.4.
    np.testing.assert_allclose(critic_targets(reward, terminal, twin, 0.9), [2.8, -2.0, -0.4])
    # One critic: 1 + 0.9·3 = 3.7; -2; -0.4.
    np.testing.assert_allclose(
        critic_targets(reward, terminal, twin[:1], 0.9), [3.7, -2.0, -0.4], rtol=1e-6
    )
    # γ = 0: the reward alone.
    np.testing.assert_allclose(critic_targets(reward, terminal, twin, 0.0), reward)


def test_bounded_targets_clip_only_where_switched_on():
    targets = jnp.array([-30.0, 5.0, 17.5, 20.0])
    np.testing.assert_array_equal(
        bounded_targets(targets, -17.5, 17.5, 1.0), [-17.5, 5.0, 17.5, 17.5]
    )
    np.testing.assert_array_equal(bounded_targets(targets, -17.5, 17.5, 0.0), targets)
    # The switch is traced: one vmapped population can hold both settings.
    both = jax.vmap(bounded_targets, in_axes=(None, None, None, 0))(
        targets, -1.0, 1.0, jnp.array([0.0, 1.0])
    )
    np.testing.assert_array_equal(both, [targets, [-1.0, 1.0, 1.0, 1.0]])


def test_critic_losses_per_critic():
    q = jnp.array([[1.0, 2.0], [0.0, 0.0]])
    targets = jnp.array([2.0, 0.0])
    # Critic 0: ((2-1)² + (0-2)²)/2 = 2.5; critic 1: (4 + 0)/2 = 2.
    np.testing.assert_allclose(critic_losses(q, targets), [2.5, 2.0])
    # No gradient flows into the targets.
    np.testing.assert_array_equal(jax.grad(lambda t: critic_losses(q, t).sum())(targets), 0.0)


def test_smoothed_target_actions_by_hand():
    target = jnp.array([[0.95, 0.9], [0.5, -0.95], [0.05, 0.0], [0.5, 0.5]])
    sigma, clip = 0.3, 0.2
    key = jax.random.key(7)
    xi = np.asarray(jax.random.normal(key, target.shape))  # the draws the function makes
    noise = np.clip(sigma * xi, -clip, clip)
    expected = np.clip(np.asarray(target) + noise, [0.0, -1.0], [1.0, 1.0])
    got = smoothed_target_actions(key, target, sigma, clip)
    np.testing.assert_allclose(got, expected, atol=1e-7)
    # This key exercises both clips: the noise clip and the action box.
    assert (np.abs(sigma * xi) > clip).any()
    assert ((np.asarray(target) + noise < [0.0, -1.0]) | (np.asarray(target) + noise > 1.0)).any()
    # σ̄ = 0: only the box clip (identity inside the box).
    np.testing.assert_allclose(smoothed_target_actions(key, target, 0.0, clip), target)
    # Huge σ̄: every noise entry saturates at ±c.
    sat = np.asarray(smoothed_target_actions(key, jnp.full((4, 2), 0.5), 1e6, clip))
    np.testing.assert_allclose(np.abs(sat - 0.5), clip, atol=1e-6)


def test_clip_action_box():
    a = jnp.array([[-0.5, -1.5], [1.5, 1.5], [0.3, -0.2]])
    np.testing.assert_allclose(clip_action(a), [[0.0, -1.0], [1.0, 1.0], [0.3, -0.2]])


def test_soft_update_by_hand():
    target = {"w": jnp.array([1.0, 2.0]), "b": jnp.array(3.0)}
    online = {"w": jnp.array([3.0, 0.0]), "b": jnp.array(-1.0)}
    out = soft_update(target, online, 0.1)
    # 0.1·3 + 0.9·1 = 1.2; 0.1·0 + 0.9·2 = 1.8; 0.1·(-1) + 0.9·3 = 2.6.
    np.testing.assert_allclose(out["w"], [1.2, 1.8], rtol=1e-6)
    np.testing.assert_allclose(out["b"], 2.6, rtol=1e-6)
    np.testing.assert_allclose(soft_update(target, online, 1.0)["w"], online["w"])
