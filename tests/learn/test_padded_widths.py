"""Hidden widths computed padded to a multiple (networks.WIDTH_ALIGN, ``width_align``).

The padding lives only in the arithmetic: the parameter tree, its shapes and initial values
are the unpadded networks'; the outputs, the parameter gradients and ∇_a Q agree with them
to fp32 rounding (close in bf16); a learner step lands where the unpadded learner's does;
and the padded program computes its GEMMs at the padded widths (which is the point).
"""

from __future__ import annotations

import re
from types import SimpleNamespace

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from advisor_jax.agent import networks
from advisor_jax.agent.learner import make_learner
from advisor_jax.contract import spec
from tests.learn.conftest import SMALL, assert_learner_steps_match

# Widths like the paper's 300 and 500: not multiples of 8.
ACTOR_HIDDEN = (40, 28)
CFG = SimpleNamespace(critic_state_hidden=48, critic_hidden=(20, 36))
N = 33  # batch


def _nets(precision: str, width_align: int):
    return (
        networks.make_actor(ACTOR_HIDDEN, precision, width_align=width_align),
        networks.make_critic(CFG, precision, width_align=width_align),
    )


@pytest.fixture(scope="module")
def data():
    rng = np.random.default_rng(3)
    actor, critic = _nets("fp32", 1)
    k_actor, k_critic = jax.random.split(jax.random.PRNGKey(5))
    noisy = lambda p: jax.tree.map(  # noqa: E731  (biases away from their zero init)
        lambda x: x + 0.1 * rng.normal(size=x.shape).astype(np.float32), p
    )
    return SimpleNamespace(
        actor=noisy(networks.init_actor(actor, k_actor)),
        critic=noisy(networks.init_critics(critic, k_critic, 2)),
        obs=jnp.asarray(rng.uniform(0, 1, (N, spec.OBS_SIZE)), jnp.float32),
        action=jnp.asarray(rng.uniform(-1, 1, (N, spec.ACTION_SIZE)), jnp.float32),
    )


def _close(a, b, rtol, err_msg=""):
    for (path, x), y in zip(
        jax.tree_util.tree_leaves_with_path(a), jax.tree.leaves(b), strict=True
    ):
        x, y = np.asarray(x, np.float32), np.asarray(y, np.float32)
        atol = rtol * max(float(np.abs(y).max()), 1e-30)
        np.testing.assert_allclose(x, y, rtol=rtol, atol=atol, err_msg=f"{err_msg} {path}")


def test_off_by_default_and_bad_values_named(monkeypatch):
    assert networks.make_actor(ACTOR_HIDDEN).width_align == 1
    assert networks.make_critic(CFG, "bf16").width_align == 1
    monkeypatch.setattr(networks, "WIDTH_ALIGN", 8)
    assert networks.make_actor(ACTOR_HIDDEN).width_align == 8
    assert networks.make_critic(CFG, width_align=1).width_align == 1
    with pytest.raises(ValueError, match="width_align must be a positive integer, got 0"):
        networks.make_critic(CFG, width_align=0)
    with pytest.raises(ValueError, match="exclude each other"):
        networks.make_actor(ACTOR_HIDDEN, bias_in_gemm=True, width_align=8).init(
            jax.random.PRNGKey(0), jnp.zeros((1, spec.OBS_SIZE))
        )


def test_the_parameters_are_the_unpadded_networks(data):
    for align in (8, 16):
        actor, critic = _nets("fp32", align)
        key = jax.random.PRNGKey(9)
        padded = networks.init_actor(actor, key), networks.init_critics(critic, key, 2)
        plain = (
            networks.init_actor(_nets("fp32", 1)[0], key),
            networks.init_critics(_nets("fp32", 1)[1], key, 2),
        )
        assert jax.tree.structure(padded) == jax.tree.structure(plain)
        for x, y in zip(jax.tree.leaves(padded), jax.tree.leaves(plain), strict=True):
            np.testing.assert_array_equal(x, y)


@pytest.mark.parametrize(("precision", "rtol"), [("fp32", 2e-5), ("bf16", 2e-2)])
def test_outputs_and_gradients_match_the_unpadded_networks(data, precision, rtol):
    (actor, critic), (plain_actor, plain_critic) = _nets(precision, 8), _nets(precision, 1)

    def q_loss(critic_net):
        def loss(params):
            q = networks.apply_critics(critic_net, params, data.obs, data.action, False)
            return jnp.sum(jnp.square(q)), q

        return jax.value_and_grad(loss, has_aux=True)(data.critic)

    def grad_a(critic_net):
        first = jax.tree.map(lambda x: x[0], data.critic)
        return jax.grad(lambda a: jnp.sum(critic_net.apply(first, data.obs, a)))(data.action)

    def actor_vjp(actor_net):
        out, pull = jax.vjp(lambda p: actor_net.apply(p, data.obs), data.actor)
        return out, pull(jnp.ones_like(out))[0]

    _close(q_loss(critic), q_loss(plain_critic), rtol, "critic loss, Q, gradients")
    _close(grad_a(critic), grad_a(plain_critic), rtol, "∇_a Q")
    _close(actor_vjp(actor), actor_vjp(plain_actor), rtol, "actor and its vjp")


def test_the_padded_program_computes_at_the_padded_widths(data):
    """The critic's 20-wide layer runs as a 24-wide GEMM, the actor's 28-wide as 32; the
    unpadded program has no such widths."""
    widths = {}
    for align in (8, 1):
        actor, critic = _nets("fp32", align)
        text = (
            jax.jit(
                lambda a, c, critic=critic, actor=actor: (
                    critic.apply(jax.tree.map(lambda x: x[0], c), data.obs, data.action),
                    actor.apply(a, data.obs),
                )
            )
            .lower(data.actor, data.critic)
            .as_text()
        )
        widths[align] = {int(w) for w in re.findall(rf"tensor<{N}x(\d+)xf32>", text)}
    assert {24, 32} <= widths[8]
    assert not {24, 32} & widths[1]


def test_learner_steps_match_the_unpadded_learner(agents, random_batch, monkeypatch):
    """ATD3+AfDP at SMALL sizes (multiples of 8) padded to multiples of 24: the same initial
    state, and a critic step and an actor step land where the unpadded learner's do."""
    plain = agents["atd3"]
    monkeypatch.setattr(networks, "WIDTH_ALIGN", 24)
    assert_learner_steps_match(
        make_learner(plain.cfg), plain, random_batch(22, SMALL["batch_size"])
    )
