"""Imitation (agent/imitation.py): the actor learns the demonstrator on states it never saw.

docs/baselines.md, "Tests" 1: synthetic observations over the contract's ranges, the
advisor's clean actions as labels, a held-out split; after a few hundred Adam steps the
held-out mean ‖π(s) − a_adv‖² falls below a quarter of its initial value.
"""

from __future__ import annotations

import jax
import jax.numpy as jnp
import numpy as np

from advisor_jax.agent.advisor import AdvisorParams, advisor_action
from advisor_jax.agent.imitation import imitation_init, imitation_loss, imitation_step
from advisor_jax.agent.networks import init_actor, make_actor


def _observations(n: int, seed: int) -> np.ndarray:
    rng = np.random.default_rng(seed)
    return np.concatenate(
        [
            rng.uniform(0.0, 1.0, (n, 16)),  # P: free distances
            rng.uniform(-np.pi, np.pi, (n, 1)),  # δ
            rng.uniform(0.0, 5.0, (n, 1)),  # d
            rng.uniform(-1.0, 1.0, (n, 2)),  # v_x, v_y
        ],
        axis=1,
    ).astype(np.float32)


def test_imitation_reduces_held_out_distance_to_the_advisor():
    obs = jnp.asarray(_observations(2500, seed=0))
    labels = jax.vmap(advisor_action, in_axes=(0, None))(obs, AdvisorParams())
    train_obs, train_labels = obs[:2000], labels[:2000]
    held_obs, held_labels = obs[2000:], labels[2000:]
    actor = make_actor((64, 64))
    params = init_actor(actor, jax.random.PRNGKey(0))

    @jax.jit
    def fit(params, key):
        def step(carry, k):
            params, opt = carry
            idx = jax.random.randint(k, (256,), 0, train_obs.shape[0])
            params, opt, metrics = imitation_step(
                actor, params, opt, train_obs[idx], train_labels[idx], 1e-3
            )
            return (params, opt), metrics["bc/loss"]

        (params, _), losses = jax.lax.scan(
            step, (params, imitation_init(params)), jax.random.split(key, 300)
        )
        return params, losses

    before = float(imitation_loss(actor, params, held_obs, held_labels))
    fitted, losses = fit(params, jax.random.PRNGKey(1))
    after = float(imitation_loss(actor, fitted, held_obs, held_labels))
    assert np.all(np.isfinite(losses))
    assert after < before / 4, (before, after)
    # The loss is Eq. 3's form: the batch mean of the squared distance summed over V and ω.
    pred = actor.apply(fitted, held_obs)
    manual = np.mean(np.sum((np.asarray(pred) - np.asarray(held_labels)) ** 2, axis=-1))
    np.testing.assert_allclose(after, manual, rtol=1e-5)


def test_imitation_step_with_zero_lr_keeps_the_actor():
    """The trainer freezes a finished agent by a zero learning rate: nothing may move."""
    actor = make_actor((8,))
    params = init_actor(actor, jax.random.PRNGKey(2))
    obs = jnp.asarray(_observations(32, seed=3))
    labels = jnp.full((32, 2), 0.5)
    step = jax.jit(lambda p, o: imitation_step(actor, p, o, obs, labels, 0.0))
    new, _, metrics = step(params, imitation_init(params))
    for a, b in zip(jax.tree.leaves(new), jax.tree.leaves(params), strict=True):
        np.testing.assert_array_equal(np.asarray(a), np.asarray(b))
    assert float(metrics["bc/loss"]) > 0 and float(metrics["bc/grad_norm"]) > 0
