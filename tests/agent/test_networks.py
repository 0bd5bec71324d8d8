"""The networks (networks.py) against plain flax layers written out here.

``nn.Dense`` layers and ``x @ K_x + a @ K_a + b`` for the critic's join: the same parameter
tree, shapes and initial values (the layout export and the numpy runner read), and in fp32
the same outputs, parameter gradients, ∇_a Q and actor vjp bit for bit.
"""

from __future__ import annotations

from collections.abc import Sequence
from functools import partial
from types import SimpleNamespace
from typing import Any

import flax.linen as nn
import jax
import jax.numpy as jnp
import numpy as np
import pytest

from advisor_jax.agent import networks
from advisor_jax.contract import spec
from tests.agent.conftest import SMALL

he_init = nn.initializers.he_normal()
CFG = SimpleNamespace(
    critic_state_hidden=SMALL["critic_state_hidden"], critic_hidden=SMALL["critic_hidden"]
)
N_CRITICS = 2


# The plain layers ----------------------


class PlainActor(nn.Module):
    hidden: Sequence[int]
    dtype: Any = jnp.float32

    @nn.compact
    def __call__(self, obs):
        x = obs
        for i, width in enumerate(self.hidden):
            dense = nn.Dense(width, kernel_init=he_init, dtype=self.dtype, name=f"hidden_{i}")
            x = nn.relu(dense(x))
        logits = nn.Dense(spec.ACTION_SIZE, kernel_init=he_init, name="head")(x)
        return jnp.stack([nn.sigmoid(logits[..., 0]), jnp.tanh(logits[..., 1])], axis=-1)


class PlainJoinDense(nn.Module):
    features: int
    dtype: Any = jnp.float32

    @nn.compact
    def __call__(self, x, a):
        n, m = x.shape[-1], a.shape[-1]

        def init(key):
            whole = he_init(key, (n + m, self.features))
            return {"state": whole[:n], "action": whole[n:]}

        kernel = self.param("kernel", init)
        bias = self.param("bias", nn.initializers.zeros_init(), (self.features,))
        x, a, k_x, k_a, bias = (
            v.astype(self.dtype) for v in (x, a, kernel["state"], kernel["action"], bias)
        )
        return x @ k_x + a @ k_a + bias


class PlainCritic(nn.Module):
    state_hidden: int
    hidden: Sequence[int]
    dtype: Any = jnp.float32

    @nn.compact
    def __call__(self, obs, action):
        dense = partial(nn.Dense, kernel_init=he_init, dtype=self.dtype)
        x = nn.relu(dense(self.state_hidden, name="state")(obs))
        x = nn.relu(PlainJoinDense(self.hidden[0], dtype=self.dtype, name="hidden_0")(x, action))
        for i, width in enumerate(self.hidden[1:], start=1):
            x = nn.relu(dense(width, name=f"hidden_{i}")(x))
        return nn.Dense(1, kernel_init=he_init, name="q")(x)[..., 0]


def _nets(precision: str):
    """(actor, critic) of networks.py at SMALL sizes and their plain twins."""
    dtype = networks.PRECISIONS[precision]
    return (
        networks.make_actor(SMALL["actor_hidden"], precision),
        networks.make_critic(CFG, precision),
        PlainActor(tuple(SMALL["actor_hidden"]), dtype),
        PlainCritic(CFG.critic_state_hidden, tuple(CFG.critic_hidden), dtype),
    )


def _with_biases(params, seed: int):
    """Every leaf moved by noise, so that the biases are not the zeros of the init."""
    rng = np.random.default_rng(seed)
    return jax.tree.map(lambda x: x + 0.1 * rng.normal(size=x.shape).astype(np.float32), params)


def _shapes(tree):
    return jax.tree.map(lambda x: (x.shape, str(x.dtype)), tree)


@pytest.mark.parametrize("precision", ["fp32", "bf16"])
def test_parameter_tree_shapes_and_initial_values_are_the_plain_layers(precision):
    actor, critic, plain_actor, plain_critic = _nets(precision)
    key = jax.random.PRNGKey(3)
    pairs = [
        (networks.init_actor(actor, key), networks.init_actor(plain_actor, key)),
        (
            networks.init_critics(critic, key, N_CRITICS),
            networks.init_critics(plain_critic, key, N_CRITICS),
        ),
    ]
    for new, plain in pairs:
        assert jax.tree.structure(new) == jax.tree.structure(plain)
        assert _shapes(new) == _shapes(plain)
        for x, y in zip(jax.tree.leaves(new), jax.tree.leaves(plain), strict=True):
            np.testing.assert_array_equal(x, y)
    # the layout export and the numpy runner read, spelled out
    actor_p, critic_p = pairs[0][0]["params"], pairs[1][0]["params"]
    (a0, a1), (s, (c0, c1)) = SMALL["actor_hidden"], (CFG.critic_state_hidden, CFG.critic_hidden)
    assert _shapes(actor_p) == {
        "hidden_0": {"kernel": ((spec.OBS_SIZE, a0), "float32"), "bias": ((a0,), "float32")},
        "hidden_1": {"kernel": ((a0, a1), "float32"), "bias": ((a1,), "float32")},
        "head": {"kernel": ((a1, spec.ACTION_SIZE), "float32"), "bias": ((2,), "float32")},
    }
    k = N_CRITICS
    assert _shapes(critic_p) == {
        "state": {"kernel": ((k, spec.OBS_SIZE, s), "float32"), "bias": ((k, s), "float32")},
        "hidden_0": {
            "kernel": {
                "state": ((k, s, c0), "float32"),
                "action": ((k, spec.ACTION_SIZE, c0), "float32"),
            },
            "bias": ((k, c0), "float32"),
        },
        "hidden_1": {"kernel": ((k, c0, c1), "float32"), "bias": ((k, c1), "float32")},
        "q": {"kernel": ((k, c1, 1), "float32"), "bias": ((k, 1), "float32")},
    }


def _critic_outputs(critic, params, obs, action):
    """Q of the stacked critics, d(Σ Q·w)/dθ and ∇_a Q (of each critic, summed over them)."""
    w = jnp.linspace(-0.5, 1.5, obs.shape[0])

    def loss(p, a):
        return jnp.sum(networks.apply_critics(critic.apply, p, obs, a) * w)

    q = networks.apply_critics(critic.apply, params, obs, action)
    g_params, g_action = jax.grad(loss, argnums=(0, 1))(params, action)
    dq_da = jax.vmap(
        jax.grad(lambda p, a: jnp.sum(critic.apply(p, obs, a)), argnums=1), in_axes=(0, None)
    )(params, action)
    return q, g_params, g_action, dq_da


def _actor_outputs(actor, params, obs):
    """π(s), and the vjp of π with a fixed cotangent: w.r.t. the parameters and the obs."""
    out, vjp = jax.vjp(actor.apply, params, obs)
    cot = jnp.stack(
        [jnp.linspace(-1.0, 1.0, obs.shape[0]), jnp.linspace(2.0, -1.0, obs.shape[0])], -1
    )
    return out, *vjp(cot)


def test_fp32_is_the_plain_layers_bit_for_bit(random_batch):
    actor, critic, plain_actor, plain_critic = _nets("fp32")
    key_actor, key_critic = jax.random.split(jax.random.PRNGKey(7))
    actor_params = _with_biases(networks.init_actor(actor, key_actor), 1)
    critic_params = _with_biases(networks.init_critics(critic, key_critic, N_CRITICS), 2)
    batch = random_batch(12, SMALL["batch_size"])
    obs, action = jnp.asarray(batch.obs), jnp.asarray(batch.action)
    for x, y in zip(
        jax.tree.leaves(_actor_outputs(actor, actor_params, obs)),
        jax.tree.leaves(_actor_outputs(plain_actor, actor_params, obs)),
        strict=True,
    ):
        np.testing.assert_array_equal(x, y)
    for x, y in zip(
        jax.tree.leaves(_critic_outputs(critic, critic_params, obs, action)),
        jax.tree.leaves(_critic_outputs(plain_critic, critic_params, obs, action)),
        strict=True,
    ):
        np.testing.assert_array_equal(x, y)
