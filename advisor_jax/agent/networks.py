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

``bias_in_gemm`` (off by default, ``BIAS_IN_GEMM``): the hidden layers add their bias inside
the matmul (the "bias row": ``[x, 1] @ [[K], [b]]``, see ``affine``); the parameters and
their layout are those of a plain ``nn.Dense`` either way, only the arithmetic changes
(H100, 128 agents: fp32 +7 %, bf16 -6 %; ``results/bench_learner_bias_row.md``).
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

BIAS_IN_GEMM = False
"""Default of ``make_actor``/``make_critic``'s ``bias_in_gemm``, read when they are called:
set it before building a learner to time or train either arithmetic in one process (a
module built with the other value traces and compiles apart). Measured on an H100
(ATD3+AfDP, 128 agents, ``results/bench_learner_bias_row.md``): fp32 +7 % (5,715 vs 5,322
agent-updates/s), bf16 -6 % (7,202 vs 7,689). Off by default because it is not
bit-identical to today's fp32 results and that gain is far below issue 17's 2× target: it
changes fixed-seed trajectories (fp32 rounding), and with it the short two-seed CPU run of
``tests/train/test_run.py`` leaves seed 0 at 12 % success, below the 20 % of the best
untrained actor (the suite's XLA flags); over 16 seeds of that run the success is
unchanged (paired difference -0.7 ± 10 points). Since fp32 learners on GPUs give each twin
critic its own inputs (``apply_critics``), the bias row on top of that is -1.4 %
(``results/bench_learner_twin_inputs/with_bias_row/``)."""

K_ALIGN = 8
"""The bias row's matmul pads its contraction dimension with zeros to a multiple of this."""

WIDTH_ALIGN = 1
"""Default of ``make_actor``/``make_critic``'s ``width_align``, read when they are called
(1: off). With 8, every hidden layer whose width is not a multiple of 8 (the paper's 300 and
500) computes at the next multiple, its kernel and bias padded with zeros on every call
(``affine``'s ``out_align``), and the next layer's kernel padded with zero rows to match:
the padded units are ReLU(0) = 0 forever (their gradients are exactly 0, so Adam leaves
their zeros alone; the parameters keep their own shapes and never hold the padding).
Why: XLA pads bf16 GEMM operands to multiples of 8 for cuBLAS itself, and where the operand
is an activation that pad is a pass over ``[agents, batch, width]``: at 64 agents in bf16
the critic's 500-wide activations padded to 504 took about 0.9 ms of a 7.0 ms training step
on an H100 (``results/profile_train/bf16_64agents_hlo/``). Padding the small weights instead
leaves no activation to pad. Measured (bf16 learner, H100, 2026-11-25, one process each,
``results/bench_learner_width_align.md``): +1.3 % at 128 agents (10,477 vs 10,343
agent-updates/s), +3.0 % at 1 agent (3,131 vs 3,041), not resolved from the run-to-run
spread by one run each; off by default until it is (``bench_learner.py --width-align 8``)."""


def _pad_axis(a: jax.Array, axis: int, size: int) -> jax.Array:
    """``a`` with zeros appended along ``axis`` up to ``size``."""
    if a.shape[axis] == size:
        return a
    widths = [(0, 0)] * a.ndim
    widths[axis] = (0, size - a.shape[axis])
    return jnp.pad(a, widths)


def affine(
    xs: Sequence[jax.Array],
    kernels: Sequence[jax.Array],
    bias: jax.Array,
    dtype: Any,
    bias_in_gemm: bool = False,
    k_align: int = K_ALIGN,
    out_align: int = 1,
) -> jax.Array:
    """``sum_i xs[i] @ kernels[i] + bias`` in ``dtype``; with ``bias_in_gemm`` as one matmul.

    Why: under ``vmap`` (a population of agents, twin critics) the bias of a layer is
    ``[agents, out]``, not one vector, and XLA's GPU GEMM rewriter fuses only a bias shared
    by the whole batched GEMM into cuBLASLt's bias epilogue (``FuseVectorBiasAdd`` in
    ``xla/service/gpu/transforms/gemm_rewriter.cc`` refuses a bias whose rank is not the
    GEMM's number of output-column dimensions, 1; cuBLASLt is never given a bias batch
    stride). Every hidden layer then ran its bias add as a separate pass over the
    ``[agents, batch, width]`` activations, its ReLU as another (the rewriter fuses a ReLU
    only into a GEMM whose output the maximum reads directly), and the backward summed
    the bias gradient over the batch in a third. On an H100 at 128 agents (ATD3+AfDP,
    paper sizes) these took 14.6 % (bias add), 14.3 % (ReLU) and 7.3 % (bias gradient) of
    the update's GPU time, while all 22 GEMMs ran with ``"epilogue":"DEFAULT"``
    (``results/profile_learner_ops.md``, ``results/profile_learner.md``). Removing the bias
    add and bias-gradient passes this way made that update 7 % faster in fp32 and 6 % slower
    in bf16 (``results/bench_learner_bias_row.md``).

    How: the bias is one more row of the weights and the input one more column of ones,
    ``concat([x..., 1]) @ concat([K..., b])``: the GEMM writes ``x @ K + b`` itself, and the
    bias gradient comes out of the weight-gradient GEMM as that row (the sum over the batch
    of the output gradient). Several ``(x_i, K_i)`` (the critic's state and action blocks)
    become one matmul over the concatenated inputs.

    The cost: the contraction dimension grows by the ones column, padded with zero columns
    to a multiple of ``k_align`` (a K of 1002 ran the critic's join layer at 78 instead of
    142 TFLOP/s on an H100, commit 64b908c), so 1000 -> 1008, 500 -> 504, 600 -> 608,
    20 -> 24; the augmented weights ``[K + pad, out]`` are concatenated on every call (the
    parameters keep their own layout), and the augmented input is a concatenation too
    (fused with the ReLU that produces it, where XLA can). The bias also goes through the
    GEMM's arithmetic: on a GPU at fp32 with JAX's default matmul precision (TF32) it is
    rounded like the weights, in bf16 it is added in the fp32 accumulator. On a CPU the
    results match ``x @ K + b`` to fp32 rounding, not bit for bit (another summation order).

    ``bias_in_gemm=False`` computes what ``nn.Dense`` does (``lax.dot_general`` per block,
    then ``+ bias``), the same operations in the same order.

    Padded widths (``WIDTH_ALIGN``): an input wider than its kernel's rows (the previous
    layer's padded output) meets the kernel padded with zero rows, and ``out_align`` > 1
    pads the kernel's columns and the bias with zeros to a multiple of it: the output is
    wider by zero units. Off (the default) nothing is padded.
    """
    if out_align > 1 or any(x.shape[-1] != k.shape[0] for x, k in zip(xs, kernels, strict=True)):
        if bias_in_gemm:
            raise ValueError(
                "padded widths (out_align, WIDTH_ALIGN) and bias_in_gemm exclude each other"
            )
        width = -(-bias.shape[-1] // out_align) * out_align
        kernels = [_pad_axis(_pad_axis(k, 0, x.shape[-1]), 1, width)
                   for x, k in zip(xs, kernels, strict=True)]  # fmt: skip
        bias = _pad_axis(bias, 0, width)
    xs = [x.astype(dtype) for x in xs]
    kernels = [k.astype(dtype) for k in kernels]
    bias = bias.astype(dtype)
    if not bias_in_gemm:
        y = None
        for x, k in zip(xs, kernels, strict=True):
            xk = jax.lax.dot_general(x, k, (((x.ndim - 1,), (0,)), ((), ())))
            y = xk if y is None else y + xk
        return y + jnp.reshape(bias, (1,) * (y.ndim - 1) + (-1,))
    lead = xs[0].shape[:-1]
    n_in = sum(x.shape[-1] for x in xs) + 1
    pad = -n_in % k_align
    x_aug = jnp.concatenate(
        [*xs, jnp.ones((*lead, 1), dtype), jnp.zeros((*lead, pad), dtype)], axis=-1
    )
    w_aug = jnp.concatenate([*kernels, bias[None], jnp.zeros((pad, bias.shape[-1]), dtype)], axis=0)
    return jax.lax.dot_general(x_aug, w_aug, (((x_aug.ndim - 1,), (0,)), ((), ())))


class Dense(nn.Module):
    """``nn.Dense`` (He kernel, zero bias, same parameter names, shapes and initial values);
    with ``bias_in_gemm`` the bias is added inside the matmul (``affine``). ``in_features``:
    the input width the parameters have when ``x`` arrives padded (``WIDTH_ALIGN``);
    ``out_align``: pad the output width to a multiple of it (``affine``)."""

    features: int
    dtype: Any = jnp.float32  # compute precision; parameters stay fp32
    bias_in_gemm: bool = False
    in_features: int | None = None  # None: x.shape[-1]
    out_align: int = 1

    @nn.compact
    def __call__(self, x: jax.Array) -> jax.Array:
        n_in = x.shape[-1] if self.in_features is None else self.in_features
        kernel = self.param("kernel", he_init, (n_in, self.features))
        bias = self.param("bias", nn.initializers.zeros_init(), (self.features,))
        return affine([x], [kernel], bias, self.dtype, self.bias_in_gemm, out_align=self.out_align)


def _head(features: int, in_features: int, width_align: int, name: str) -> nn.Module:
    """An output head in fp32: ``nn.Dense`` as always, or, with padded hidden widths, our
    ``Dense`` (the same parameters and initial values) that meets the padded input."""
    if width_align == 1:
        return nn.Dense(features, kernel_init=he_init, dtype=jnp.float32, name=name)
    return Dense(features, dtype=jnp.float32, in_features=in_features, name=name)


class Actor(nn.Module):
    """Deterministic policy π(s; φ) → (V, ω)."""

    hidden: Sequence[int] = (600, 300)
    dtype: Any = jnp.float32  # compute precision of the hidden layers (module docstring)
    bias_in_gemm: bool = False  # hidden layers add their bias in the matmul (``affine``)
    width_align: int = 1  # hidden widths computed padded to a multiple (``WIDTH_ALIGN``)

    @nn.compact
    def __call__(self, obs: jax.Array) -> jax.Array:
        x, n_in = obs, obs.shape[-1]
        for i, width in enumerate(self.hidden):
            dense = Dense(
                width,
                dtype=self.dtype,
                bias_in_gemm=self.bias_in_gemm,
                in_features=n_in,
                out_align=self.width_align,
                name=f"hidden_{i}",
            )
            x, n_in = nn.relu(dense(x)), width
        logits = _head(spec.ACTION_SIZE, n_in, self.width_align, "head")(x)
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

    With ``bias_in_gemm`` (``affine``) the two blocks and the bias are one matmul,
    ``[x, a, 1, 0…] @ [K_x; K_a; b; 0…]`` with K = 1008 (1000 + 2 + 1, padded to a multiple
    of 8), which also removes the separate add of ``a @ K_a``.
    """

    features: int
    dtype: Any = jnp.float32
    bias_in_gemm: bool = False
    in_features: int | None = None  # x's width in the parameters (``Dense``); None: x's
    out_align: int = 1

    @nn.compact
    def __call__(self, x: jax.Array, a: jax.Array) -> jax.Array:
        n, m = x.shape[-1] if self.in_features is None else self.in_features, a.shape[-1]

        def init(key):
            whole = he_init(key, (n + m, self.features))
            return {"state": whole[:n], "action": whole[n:]}

        kernel = self.param("kernel", init)
        bias = self.param("bias", nn.initializers.zeros_init(), (self.features,))
        return affine([x, a], [kernel["state"], kernel["action"]], bias, self.dtype,
                      self.bias_in_gemm, out_align=self.out_align)  # fmt: skip


class Critic(nn.Module):
    """Action-value function Q(s, a; θ); the action joins after the first layer."""

    state_hidden: int = 1000
    hidden: Sequence[int] = (500, 600)
    dtype: Any = jnp.float32  # compute precision of the hidden layers (module docstring)
    bias_in_gemm: bool = False  # hidden layers add their bias in the matmul (``affine``)
    width_align: int = 1  # hidden widths computed padded to a multiple (``WIDTH_ALIGN``)

    @nn.compact
    def __call__(self, obs: jax.Array, action: jax.Array) -> jax.Array:
        dense = partial(Dense, dtype=self.dtype, bias_in_gemm=self.bias_in_gemm,
                        out_align=self.width_align)  # fmt: skip
        x = nn.relu(dense(self.state_hidden, in_features=obs.shape[-1], name="state")(obs))
        join = JoinDense(self.hidden[0], dtype=self.dtype, bias_in_gemm=self.bias_in_gemm,
                         in_features=self.state_hidden, out_align=self.width_align,
                         name="hidden_0")  # fmt: skip
        x = nn.relu(join(x, action))
        for i, width in enumerate(self.hidden[1:], start=1):
            x = nn.relu(dense(width, in_features=self.hidden[i - 1], name=f"hidden_{i}")(x))
        return _head(1, self.hidden[-1], self.width_align, "q")(x)[..., 0]


PRECISIONS = {"fp32": jnp.float32, "bf16": jnp.bfloat16}
"""``AgentConfig.precision`` → compute dtype of the hidden layers."""


def make_actor(
    hidden: Sequence[int],
    precision: str = "fp32",
    bias_in_gemm: bool | None = None,
    width_align: int | None = None,
) -> Actor:
    """The one policy factory: π(s; φ) with these hidden widths (``AgentConfig.actor_hidden``).

    Training, evaluation, export and the CLI all build their actor here, so the widths are
    always a tuple of ints (a list would make another, unequal module). ``precision`` is
    the learner's (``AgentConfig.precision``); everything that acts (data collection,
    evaluation, export) uses the fp32 default on the same parameters. ``bias_in_gemm``:
    ``affine``; None takes ``BIAS_IN_GEMM``. ``width_align``: ``WIDTH_ALIGN``'s; None takes
    it."""
    return Actor(
        hidden=tuple(int(w) for w in hidden),
        dtype=PRECISIONS[precision],
        bias_in_gemm=BIAS_IN_GEMM if bias_in_gemm is None else bool(bias_in_gemm),
        width_align=_width_align(width_align),
    )


def make_critic(
    cfg, precision: str = "fp32", bias_in_gemm: bool | None = None, width_align: int | None = None
) -> Critic:
    """Q(s, a; θ) at ``cfg``'s (an ``AgentConfig``'s) widths and the given precision
    (``bias_in_gemm``, ``width_align``: as ``make_actor``)."""
    return Critic(
        state_hidden=cfg.critic_state_hidden,
        hidden=tuple(cfg.critic_hidden),
        dtype=PRECISIONS[precision],
        bias_in_gemm=BIAS_IN_GEMM if bias_in_gemm is None else bool(bias_in_gemm),
        width_align=_width_align(width_align),
    )


def _width_align(width_align: int | None) -> int:
    align = WIDTH_ALIGN if width_align is None else width_align
    if int(align) != align or align < 1:
        raise ValueError(f"width_align must be a positive integer, got {align!r}")
    return int(align)


def count_params(params) -> int:
    """Number of scalar parameters in a params pytree."""
    return sum(int(x.size) for x in jax.tree_util.tree_leaves(params))


def init_critics(critic: Critic, key: jax.Array, n_critics: int):
    """Params of ``n_critics`` critics stacked on a leading axis."""
    obs = jnp.zeros((1, spec.OBS_SIZE))
    act = jnp.zeros((1, spec.ACTION_SIZE))
    keys = jax.random.split(key, n_critics)
    return jax.vmap(critic.init, in_axes=(0, None, None))(keys, obs, act)


def inputs_per_critic_by_default(backend: str | None = None) -> bool:
    """``apply_critics``'s layout when none is asked for: per critic on a GPU, shared
    otherwise (``backend``: JAX's default backend when None; other accelerators are not
    measured), whatever the critic's precision.

    Measured on an H100 (ATD3+AfDP, paper sizes): fp32 per critic, +8.8 % agent-updates/s
    at 128 agents and +8.7 % agent env-steps/s at 64, no change at 1 agent (2026-11-24,
    ``results/bench_learner_twin_inputs/``). With XLA's Triton GEMMs it had cost a 1-agent
    bf16 run 13 %, so bf16 learners kept the shared layout; with their GEMMs on cuBLAS
    (``compiler_options``) they take it too (together +33 % learner at 128 agents, +29 % full
    step at 64; 2026-11-25, ``results/bench_learner_cublas/``). On CPUs
    the per-critic GEMMs sum in another order: the gradients change in their last bits
    (relative 1e-7) and with them fixed-seed trajectories, so CPU runs keep the shared
    layout and their results."""
    backend = jax.default_backend() if backend is None else backend
    return backend == "gpu"


def apply_critics(
    critic: Critic,
    params,
    obs: jax.Array,
    action: jax.Array,
    inputs_per_critic: bool | None = None,
) -> jax.Array:
    """Q-values of every stacked critic: [n_critics, ...batch].

    The critics read the same (obs, action). ``inputs_per_critic`` hands each critic its own
    (broadcast) copy of them, so that each layer is one GEMM per critic; otherwise ``vmap``
    shares them and XLA computes the twins' state layer as one wider GEMM, ``obs @ [K_1,
    K_2]``, whose output then takes a transposing pass into the per-critic layout (on an
    H100: a separate bias add over [agents, 2, batch, 1000] and a transpose for the
    backward, ``results/profile_learner_bf16/``). The same function either way, equal to
    fp32 rounding. None: ``inputs_per_critic_by_default``.
    """
    if inputs_per_critic is None:
        inputs_per_critic = inputs_per_critic_by_default()
    if not inputs_per_critic:
        return jax.vmap(critic.apply, in_axes=(0, None, None))(params, obs, action)
    n = jax.tree_util.tree_leaves(params)[0].shape[0]
    obs_n = jnp.broadcast_to(obs, (n, *obs.shape))
    action_n = jnp.broadcast_to(action, (n, *action.shape))
    return jax.vmap(critic.apply)(params, obs_n, action_n)


def init_actor(actor: Actor, key: jax.Array):
    """Params of one actor."""
    return actor.init(key, jnp.zeros((1, spec.OBS_SIZE)))
