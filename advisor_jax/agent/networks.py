"""Actor and critic networks (paper §5.3, Fig. 4).

Actor: obs 20 → 600 → 300 → 2, ReLU hidden layers; V from a sigmoid head (forward only,
[0, 1]) and ω from a tanh head ([-1, 1]). 193,502 parameters at the paper's sizes.

Critic: obs 20 → 1000, then the action is concatenated, → 500 → 600 → 1 (linear).
823,701 parameters at the paper's sizes, the count the paper states.

He initialisation (truncated normal, fan-in, variance 2/fan_in) of every kernel, zero
biases. Twin critics (TD3/ATD3) are one params tree with a leading axis of 2, initialised
and applied with ``jax.vmap``.

``dtype`` is the compute precision of the hidden layers (``AgentConfig.precision``):
float32 by default; bfloat16 casts the inputs, kernels and activations of the hidden
layers to bf16 (the GEMMs accumulate in fp32 on the tensor cores) while the parameters,
their gradients and Adam stay fp32. The output heads (the actor's two actions, the
critic's Q) always compute in fp32.

Parameter layout (what ``export`` writes): ``{"params": {"hidden_0": {"kernel": [in, out],
"bias": [out]}, ..., "head": {...}}}`` for the actor, kernels in flax ``(in, out)`` order.
"""

from __future__ import annotations

from collections.abc import Sequence
from functools import partial
from typing import Any

import flax.linen as nn
import jax
import jax.numpy as jnp

from advisor_jax.contract import spec

he_init = nn.initializers.he_normal()


class Actor(nn.Module):
    """Deterministic policy π(s; φ) → (V, ω)."""

    hidden: Sequence[int] = (600, 300)
    dtype: Any = jnp.float32  # compute precision of the hidden layers (module docstring)

    @nn.compact
    def __call__(self, obs: jax.Array) -> jax.Array:
        x = obs
        for i, width in enumerate(self.hidden):
            dense = nn.Dense(width, kernel_init=he_init, dtype=self.dtype, name=f"hidden_{i}")
            x = nn.relu(dense(x))
        head = nn.Dense(spec.ACTION_SIZE, kernel_init=he_init, dtype=jnp.float32, name="head")
        logits = head(x)
        return jnp.stack([nn.sigmoid(logits[..., 0]), jnp.tanh(logits[..., 1])], axis=-1)


class JoinDense(nn.Module):
    """``Dense(concat([x, a]))`` computed as ``x @ K_x + a @ K_a + b``.

    The same function as the concatenation and the same initial values: the kernel
    ``[n + m, out]`` is drawn once (He, fan-in n + m) and kept as its two row blocks,
    ``kernel = {"state": K[:n], "action": K[n:]}``. The large matmul keeps K = n = 1000
    instead of 1002, a multiple of the GPU's tensor-core tile (measured much faster on an
    H100 when it was introduced, commit 64b908c), and, stored apart, neither block is
    sliced out of the whole on every call (on an H100 a copy of the [1000, 500] block per
    critic and call, 2.8 % of an update at 128 agents; results/profile_learner_ops.md).
    """

    features: int
    dtype: Any = jnp.float32

    @nn.compact
    def __call__(self, x: jax.Array, a: jax.Array) -> jax.Array:
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


class Critic(nn.Module):
    """Action-value function Q(s, a; θ); the action joins after the first layer."""

    state_hidden: int = 1000
    hidden: Sequence[int] = (500, 600)
    dtype: Any = jnp.float32  # compute precision of the hidden layers (module docstring)

    @nn.compact
    def __call__(self, obs: jax.Array, action: jax.Array) -> jax.Array:
        dense = partial(nn.Dense, kernel_init=he_init, dtype=self.dtype)
        x = nn.relu(dense(self.state_hidden, name="state")(obs))
        x = nn.relu(JoinDense(self.hidden[0], dtype=self.dtype, name="hidden_0")(x, action))
        for i, width in enumerate(self.hidden[1:], start=1):
            x = nn.relu(dense(width, name=f"hidden_{i}")(x))
        return nn.Dense(1, kernel_init=he_init, dtype=jnp.float32, name="q")(x)[..., 0]


PRECISIONS = {"fp32": jnp.float32, "bf16": jnp.bfloat16}
"""``AgentConfig.precision`` → compute dtype of the hidden layers."""


def make_actor(hidden: Sequence[int], precision: str = "fp32") -> Actor:
    """The one policy factory: π(s; φ) with these hidden widths (``AgentConfig.actor_hidden``).

    Training, evaluation, export and the CLI all build their actor here, so the widths are
    always a tuple of ints (a list would make another, unequal module). ``precision`` is
    the learner's (``AgentConfig.precision``); everything that acts (data collection,
    evaluation, export) uses the fp32 default on the same parameters."""
    return Actor(hidden=tuple(int(w) for w in hidden), dtype=PRECISIONS[precision])


def make_critic(cfg, precision: str = "fp32") -> Critic:
    """Q(s, a; θ) at ``cfg``'s (an ``AgentConfig``'s) widths and the given precision."""
    return Critic(
        state_hidden=cfg.critic_state_hidden,
        hidden=tuple(cfg.critic_hidden),
        dtype=PRECISIONS[precision],
    )


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
