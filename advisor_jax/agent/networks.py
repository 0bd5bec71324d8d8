"""Actor and critic networks (paper §5.3, Fig. 4).

Actor: obs 20 → 600 → 300 → 2, ReLU hidden layers; V from a sigmoid head (forward only,
[0, 1]) and ω from a tanh head ([-1, 1]). 193,502 parameters at the paper's sizes.

Critic: obs 20 → 1000, then the action is concatenated, → 500 → 600 → 1 (linear).
823,701 parameters at the paper's sizes, the count the paper states.

He initialisation (truncated normal, fan-in, variance 2/fan_in) of every kernel, zero
biases. Twin critics (TD3/ATD3) are one params tree with a leading axis of 2, initialised
and applied with ``jax.vmap``.

Parameter layout (what ``export`` writes): ``{"params": {"hidden_0": {"kernel": [in, out],
"bias": [out]}, ..., "head": {...}}}`` for the actor, kernels in flax ``(in, out)`` order.
"""

from __future__ import annotations

from collections.abc import Sequence

import flax.linen as nn
import jax
import jax.numpy as jnp

from advisor_jax.contract import spec

he_init = nn.initializers.he_normal()


class Actor(nn.Module):
    """Deterministic policy π(s; φ) → (V, ω)."""

    hidden: Sequence[int] = (600, 300)

    @nn.compact
    def __call__(self, obs: jax.Array) -> jax.Array:
        x = obs
        for i, width in enumerate(self.hidden):
            x = nn.relu(nn.Dense(width, kernel_init=he_init, name=f"hidden_{i}")(x))
        logits = nn.Dense(spec.ACTION_SIZE, kernel_init=he_init, name="head")(x)
        return jnp.stack([nn.sigmoid(logits[..., 0]), jnp.tanh(logits[..., 1])], axis=-1)


class JoinDense(nn.Module):
    """``Dense(concat([x, a]))`` computed as ``x @ K[:n] + a @ K[n:] + b``.

    Same parameters (one kernel [n + m, out], He-initialised with fan-in n + m) and the same
    function as the concatenation, but the large matmul keeps K = n = 1000 instead of 1002,
    a multiple of the GPU's tensor-core tile (the split layer was measured much faster on
    an H100 when it was introduced, commit 64b908c).
    """

    features: int

    @nn.compact
    def __call__(self, x: jax.Array, a: jax.Array) -> jax.Array:
        n = x.shape[-1]
        kernel = self.param("kernel", he_init, (n + a.shape[-1], self.features))
        bias = self.param("bias", nn.initializers.zeros_init(), (self.features,))
        return x @ kernel[:n] + a @ kernel[n:] + bias


class Critic(nn.Module):
    """Action-value function Q(s, a; θ); the action joins after the first layer."""

    state_hidden: int = 1000
    hidden: Sequence[int] = (500, 600)

    @nn.compact
    def __call__(self, obs: jax.Array, action: jax.Array) -> jax.Array:
        x = nn.relu(nn.Dense(self.state_hidden, kernel_init=he_init, name="state")(obs))
        x = nn.relu(JoinDense(self.hidden[0], name="hidden_0")(x, action))
        for i, width in enumerate(self.hidden[1:], start=1):
            x = nn.relu(nn.Dense(width, kernel_init=he_init, name=f"hidden_{i}")(x))
        return nn.Dense(1, kernel_init=he_init, name="q")(x)[..., 0]


def make_actor(hidden: Sequence[int]) -> Actor:
    """The one policy factory: π(s; φ) with these hidden widths (``AgentConfig.actor_hidden``).

    Training, evaluation, export and the CLI all build their actor here, so the widths are
    always a tuple of ints (a list would make another, unequal module)."""
    return Actor(hidden=tuple(int(w) for w in hidden))


def count_params(params) -> int:
    """Number of scalar parameters in a params pytree."""
    return sum(int(x.size) for x in jax.tree_util.tree_leaves(params))


def init_critics(critic: Critic, key: jax.Array, n_critics: int):
    """Params of ``n_critics`` critics stacked on a leading axis."""
    obs = jnp.zeros((1, spec.OBS_SIZE))
    act = jnp.zeros((1, spec.ACTION_SIZE))
    keys = jax.random.split(key, n_critics)
    return jax.vmap(critic.init, in_axes=(0, None, None))(keys, obs, act)


def apply_critics(critic: Critic, params, obs: jax.Array, action: jax.Array) -> jax.Array:
    """Q-values of every stacked critic: [n_critics, ...batch]."""
    return jax.vmap(critic.apply, in_axes=(0, None, None))(params, obs, action)


def init_actor(actor: Actor, key: jax.Array):
    """Params of one actor."""
    return actor.init(key, jnp.zeros((1, spec.OBS_SIZE)))
