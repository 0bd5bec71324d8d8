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

from collections.abc import Callable, Sequence
from functools import partial
from typing import Any, NamedTuple

import flax.linen as nn
import jax
import jax.numpy as jnp

from advisor_jax.agent import gemm_layers
from advisor_jax.contract import spec

he_init = nn.initializers.he_normal()


def affine(xs: Sequence[jax.Array], kernels: Sequence[jax.Array], bias: jax.Array, dtype: Any):
    """``sum_i xs[i] @ kernels[i] + bias`` computed in ``dtype``: what ``nn.Dense`` computes
    (``lax.dot_general`` per block, then ``+ bias``), the same operations in the same order,
    with the critic's join layer as two blocks (``JoinDense``)."""
    xs = [x.astype(dtype) for x in xs]
    kernels = [k.astype(dtype) for k in kernels]
    bias = bias.astype(dtype)
    y = None
    for x, k in zip(xs, kernels, strict=True):
        xk = jax.lax.dot_general(x, k, (((x.ndim - 1,), (0,)), ((), ())))
        y = xk if y is None else y + xk
    return y + jnp.reshape(bias, (1,) * (y.ndim - 1) + (-1,))


class Dense(nn.Module):
    """``nn.Dense`` (He kernel, zero bias, same parameter names, shapes and initial values)
    computing in ``dtype`` while its parameters stay fp32."""

    features: int
    dtype: Any = jnp.float32  # compute precision; parameters stay fp32

    @nn.compact
    def __call__(self, x: jax.Array) -> jax.Array:
        kernel = self.param("kernel", he_init, (x.shape[-1], self.features))
        bias = self.param("bias", nn.initializers.zeros_init(), (self.features,))
        return affine([x], [kernel], bias, self.dtype)


class Actor(nn.Module):
    """Deterministic policy π(s; φ) → (V, ω)."""

    hidden: Sequence[int] = (600, 300)
    dtype: Any = jnp.float32  # compute precision of the hidden layers (module docstring)

    @nn.compact
    def __call__(self, obs: jax.Array) -> jax.Array:
        x = obs
        for i, width in enumerate(self.hidden):
            x = nn.relu(Dense(width, dtype=self.dtype, name=f"hidden_{i}")(x))
        logits = nn.Dense(spec.ACTION_SIZE, kernel_init=he_init, dtype=jnp.float32, name="head")(x)
        return jnp.stack([nn.sigmoid(logits[..., 0]), jnp.tanh(logits[..., 1])], axis=-1)


class JoinDense(nn.Module):
    """``Dense(concat([x, a]))`` computed as ``x @ K_x + a @ K_a + b``.

    The same function as the concatenation and the same initial values: the kernel
    ``[n + m, out]`` is drawn once (He, fan-in n + m) and kept as its two row blocks,
    ``kernel = {"state": K[:n], "action": K[n:]}``. The large matmul keeps its contraction
    at n = 1000 instead of 1002, a multiple of the GPU's tensor-core tile, and, stored apart,
    neither block is sliced out of the whole on every call (``results/profile_learner_ops.md``).
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
        return affine([x, a], [kernel["state"], kernel["action"]], bias, self.dtype)


class Critic(nn.Module):
    """Action-value function Q(s, a; θ); the action joins after the first layer."""

    state_hidden: int = 1000
    hidden: Sequence[int] = (500, 600)
    dtype: Any = jnp.float32  # compute precision of the hidden layers (module docstring)

    @nn.compact
    def __call__(self, obs: jax.Array, action: jax.Array) -> jax.Array:
        dense = partial(Dense, dtype=self.dtype)
        x = nn.relu(dense(self.state_hidden, name="state")(obs))
        x = nn.relu(JoinDense(self.hidden[0], dtype=self.dtype, name="hidden_0")(x, action))
        for i, width in enumerate(self.hidden[1:], start=1):
            x = nn.relu(dense(width, name=f"hidden_{i}")(x))
        return nn.Dense(1, kernel_init=he_init, dtype=jnp.float32, name="q")(x)[..., 0]


class Layout(NamedTuple):
    """How a learner's networks are computed and stored on its device: the same function and
    parameters either way, equal to rounding. ``training.program.network_layout`` chooses
    (all on GPUs, none on CPUs, whose results then stay bit for bit)."""

    inputs_per_critic: bool = False
    """Each twin critic reads its own copy of the inputs (``apply_critics``)."""
    layers_in_gemm: bool = False
    """Each hidden layer one GEMM with its bias inside (``gemm_layers``)."""
    first_layer_kernel: bool = False
    """With ``layers_in_gemm``: the critic's first layer's weight gradient and ReLU mask in one
    kernel (``masked_wgrad``)."""
    bf16_first_moment: bool = False
    """A bf16 learner's Adam keeps its first moment in bf16 (``optax.adam``'s ``mu_dtype``):
    fewer of the optimizer's bytes; the parameters and every fp32 learner stay fp32."""
    bf16_second_moment: bool = False
    """A bf16 learner's Adam keeps its second moment in bf16, stochastically rounded
    (``agent/adam.py``); the parameters and every fp32 learner stay fp32."""
    held_critics: bool = False
    """With ``layers_in_gemm``: through a training chunk the critics' augmented matrices are
    their parameters, so that no step builds them (``held_critics``)."""
    head_sums: bool = False
    """With ``layers_in_gemm``: a bf16 network's fp32 output head from its bf16 activations as
    products summed per output, not a cast and a GEMM (``gemm_layers``' ``head_sums``)."""
    bf16_critic_weights: bool = False
    """With ``held_critics``: a bf16 learner's held critics keep their hidden matrices (θ and
    θ^T) in bf16 only, each update rounded stochastically (``held_critics.hold``'s
    ``in_dtype``): no fp32 master to read and write, no copy to write."""
    hidden_align: int = gemm_layers.ALIGN
    """With ``layers_in_gemm``: the hidden layers' widths of at least 8 × this are padded to its
    multiples (``gemm_layers.padded``), the others to ``gemm_layers.ALIGN``."""


MODULES = Layout()
"""The flax modules as written, the twins sharing their inputs: the CPU's layout."""


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


class NetworkFunctions(NamedTuple):
    """How a learner computes one network: ``forward(build(params), *inputs)`` is the network's
    ``apply(params, *inputs)``. ``build`` turns the parameters into what ``forward`` multiplies
    by (``gemm_layers``' augmented matrices; the parameters themselves for the flax modules):
    built once, it serves several passes (``agent.learner``'s target networks)."""

    build: Callable
    forward: Callable

    def apply(self, params, *inputs):
        return self.forward(self.build(params), *inputs)


def _unchanged(params):
    return params


def learner_functions(
    actor: Actor, critic: Critic, layout: Layout
) -> tuple[NetworkFunctions, NetworkFunctions]:
    """(actor, critic) functions of the learner's networks ``actor`` and ``critic``: the
    modules' ``apply``, or with ``layout.layers_in_gemm`` the same functions as
    ``gemm_layers`` computes them at the modules' precision."""
    if not layout.layers_in_gemm:
        return NetworkFunctions(_unchanged, actor.apply), NetworkFunctions(_unchanged, critic.apply)
    return (
        NetworkFunctions(partial(gemm_layers.actor_matrices, dtype=actor.dtype,
                                 align=layout.hidden_align),
                         partial(gemm_layers.actor_forward, head_sums=layout.head_sums)),
        NetworkFunctions(partial(gemm_layers.critic_matrices, dtype=critic.dtype,
                                 align=layout.hidden_align),
                         partial(gemm_layers.critic_forward,
                                 first_layer_kernel=layout.first_layer_kernel,
                                 head_sums=layout.head_sums)),
    )  # fmt: skip


def count_params(params) -> int:
    """Number of scalar parameters in a params pytree."""
    return sum(int(x.size) for x in jax.tree_util.tree_leaves(params))


def init_critics(critic: Critic, key: jax.Array, n_critics: int):
    """Params of ``n_critics`` critics stacked on a leading axis."""
    obs = jnp.zeros((1, spec.OBS_SIZE))
    act = jnp.zeros((1, spec.ACTION_SIZE))
    keys = jax.random.split(key, n_critics)
    return jax.vmap(critic.init, in_axes=(0, None, None))(keys, obs, act)


def apply_critics(
    critic_apply: Callable,
    params,
    obs: jax.Array,
    action: jax.Array,
    inputs_per_critic: bool = False,
) -> jax.Array:
    """Q-values of every stacked critic: [n_critics, ...batch]; ``critic_apply``: (params,
    obs, action) -> Q, a ``Critic``'s ``apply`` or ``gemm_layers.critic_apply``.

    The critics read the same (obs, action). ``inputs_per_critic`` hands each critic its own
    (broadcast) copy of them, so that each layer is one GEMM per critic; otherwise ``vmap``
    shares them and XLA computes the twins' state layer as one wider GEMM, ``obs @ [K_1,
    K_2]``, whose output then takes a transposing pass into the per-critic layout (on a GPU:
    a separate bias add over [agents, 2, batch, 1000] and a transpose for the backward,
    ``results/profile_learner_bf16/``). The same function either way, equal to
    fp32 rounding, not bit for bit; ``training.program.twin_inputs_per_critic`` chooses.
    """
    if not inputs_per_critic:
        return jax.vmap(critic_apply, in_axes=(0, None, None))(params, obs, action)
    n = jax.tree_util.tree_leaves(params)[0].shape[0]
    obs_n = jnp.broadcast_to(obs, (n, *obs.shape))
    action_n = jnp.broadcast_to(action, (n, *action.shape))
    return jax.vmap(critic_apply)(params, obs_n, action_n)


def init_actor(actor: Actor, key: jax.Array):
    """Params of one actor."""
    return actor.init(key, jnp.zeros((1, spec.OBS_SIZE)))
