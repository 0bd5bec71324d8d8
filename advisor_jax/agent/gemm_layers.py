"""The actor and critic of ``networks``, every hidden layer one GEMM: bias and ReLU inside.

A hidden layer ``relu(x @ K + b)`` is, on a GPU, a GEMM and then a pass over its output for
the bias add and the ReLU; its backward reduces the batch in another pass for the bias
gradient (``results/profile_learner_ops.md``: 12 % and 7 % of a 128-agent update). Here the
input of every hidden layer carries a column of ones, so the bias is a row of the layer's
matrix (the *augmented* matrix) and its gradient a row of the weight gradient; each layer
writes the ones column of the next one itself (a matrix column that is 0 but for a 1 in the
bias row: ``relu(1) = 1``). What follows the GEMM is then the ReLU alone, which cuBLASLt can
run in the GEMM's epilogue (``training.compiler.compiler_options``); ``relu`` keeps the output
as the residual of its backward, so the GEMM's result has no other reader.

The critic's action joins after its first layer (``networks.JoinDense``: ``x @ K_x + a @ K_a
+ b``). Its ``a @ K_a`` would be another GEMM and another pass between the GEMM and the ReLU,
so the action enters the first layer's input instead and that layer passes it on as
``relu(a)`` and ``relu(-a)`` (columns of ±1); the join layer's matrix holds ``K_a`` against
``relu(a)`` and ``-K_a`` against ``relu(-a)``: ``relu(a) K_a - relu(-a) K_a = a K_a``, one of
the two terms 0, exactly.

Widths are padded with zero columns to multiples of ``ALIGN`` (the tensor cores' 16 bytes
at bf16); a padding column stays 0 (``relu(0)``) and gets a zero gradient. At the paper's
sizes the critic's GEMMs are [24 → 1008 → 504 → 608], 2 % more multiply-adds than
[22 → 1004 → 500 → 600]. A wider ``align`` (``networks.Layout.hidden_align``) pads the hidden
layers' outputs of at least ``8 · align`` columns to its multiples: at 32, [24 → 1024 → 512 →
608], the shapes cuBLAS runs faster (``training.program.ALIGNED_WIDTHS``).

The same parameters (the flax trees that ``networks.Actor`` / ``networks.Critic`` initialise,
and their gradients in the same trees) and the same function: the sums differ only in order
and rounding (the bias is summed in the GEMM's fp32 accumulator rather than added after the
rounding to ``dtype``), so results are equal to rounding, not bit for bit
(``tests/agent/test_gemm_layers.py``). ``training.program.layers_in_gemm`` chooses where it
runs.
"""

from __future__ import annotations

from collections.abc import Sequence
from typing import Any

import jax
import jax.numpy as jnp

from advisor_jax.agent import masked_wgrad

ALIGN = 8
"""GEMM widths are padded to a multiple of this (16 bytes of bf16)."""


def padded(n: int, align: int = ALIGN) -> int:
    """``n`` rounded up to a multiple of ``align`` where that adds at most an eighth (``n ≥
    8 · align``), else of ``ALIGN``."""
    step = align if n >= 8 * align else ALIGN
    return -(-n // step) * step


@jax.custom_vjp
def relu(x: jax.Array) -> jax.Array:
    """``max(x, 0)`` whose backward masks by the output (``y > 0`` iff ``x > 0``), so that
    the pre-activation, the GEMM's result, is read by the ReLU alone."""
    return jnp.maximum(x, jnp.zeros((), x.dtype))


def _relu_forward(x):
    y = relu(x)
    return y, y


def _relu_backward(y, g):
    # The barrier keeps XLA's simplifier from rewriting ``max(x, 0) > 0`` as ``x > 0``, which
    # would make the GEMM's result a residual again and its ReLU no longer an epilogue.
    return (jnp.where(jax.lax.optimization_barrier(y) > 0, g, jnp.zeros((), g.dtype)),)


relu.defvjp(_relu_forward, _relu_backward)


def with_ones(x: jax.Array, dtype: Any) -> jax.Array:
    """A first layer's input ``[..., k]`` → ``[..., padded(k + 1)]``: x, a column of ones,
    zeros; in ``dtype``."""
    k = x.shape[-1]
    ones = jnp.ones((*x.shape[:-1], 1), x.dtype)
    zeros = jnp.zeros((*x.shape[:-1], padded(k + 1) - k - 1), x.dtype)
    return jnp.concatenate([x, ones, zeros], axis=-1).astype(dtype)


def _placed(block: jax.Array, row: int, col: int, shape: tuple[int, int]) -> jax.Array:
    """``block`` at (``row``, ``col``) of a zero matrix of ``shape``."""
    (r, c), (n_rows, n_cols) = block.shape, shape
    pads = ((row, n_rows - row - r, 0), (col, n_cols - col - c, 0))
    return jax.lax.pad(block, jnp.zeros((), block.dtype), pads)


def layer_matrix(
    blocks: Sequence[tuple[jax.Array, int]],
    bias: jax.Array,
    k_in: int,
    dtype: Any,
    align: int = ALIGN,
) -> jax.Array:
    """The augmented matrix of a hidden layer, ``[k_in, padded(n + 1, align)]``, in ``dtype``:
    ``[[rows, 0, 0], [bias, 1, 0], [0, 0, 0]]``, where ``rows`` ``[k, n]`` is ``blocks``
    (``(block, first column)`` pairs) stacked, each block at its column and 0 elsewhere.
    Against an input ``[x, 1, 0…]`` it gives ``[x @ rows + bias, 1, 0…]``.

    Built as a sum of zero-padded pieces, one elementwise pass that XLA fuses with the
    cast: the pass the unaugmented weights took for their cast to bf16 alone (a
    concatenation instead compiles to a kernel that took twice as long on an H100)."""
    n = bias.shape[0]
    shape = (k_in, padded(n + 1, align))
    bias_row = jnp.concatenate([bias, jnp.ones((1,), bias.dtype)])[None]
    matrix, row = _placed(bias_row, sum(b.shape[0] for b, _ in blocks), 0, shape), 0
    for block, col in blocks:
        matrix = matrix + _placed(block, row, col, shape)
        row += block.shape[0]
    return matrix.astype(dtype)


def head_matrix(kernel: jax.Array, bias: jax.Array, k_in: int) -> jax.Array:
    """An output head's ``[k_in, n]`` = ``[[kernel], [bias], [0]]`` (fp32, no ones column)."""
    k, n = kernel.shape
    return _placed(kernel, 0, 0, (k_in, n)) + _placed(bias[None], k, 0, (k_in, n))


def _dot(x: jax.Array, matrix: jax.Array) -> jax.Array:
    return jax.lax.dot_general(x, matrix, (((x.ndim - 1,), (0,)), ((), ())))


def _hidden(x: jax.Array, matrix: jax.Array) -> jax.Array:
    """One hidden layer on an augmented input with its augmented matrix: ``relu(x @ matrix)``."""
    return relu(_dot(x, matrix))


@jax.custom_vjp
def first_critic_layer(x: jax.Array, matrix: jax.Array) -> jax.Array:
    """``_hidden(x, matrix)`` for the critic's first layer, ``x [n, k]`` its augmented input,
    whose weight gradient is one kernel with the ReLU's mask (``masked_wgrad``)."""
    return _hidden(x, matrix)


def _first_critic_layer_forward(x, matrix):
    y = _hidden(x, matrix)
    return y, (x, matrix, y)


def _first_critic_layer_backward(residuals, g):
    x, matrix, y = residuals
    (masked,) = _relu_backward(y, g)  # read only by the input's gradient, if anyone wants it
    d_x = jax.lax.dot_general(masked, matrix, (((1,), (1,)), ((), ())))
    if matrix.dtype == jnp.bfloat16:  # exact products: the kernel recomputes the mask
        return d_x, masked_wgrad.weight_gradient_from_input(x, matrix, g)
    return d_x, masked_wgrad.weight_gradient(x, y, g)


first_critic_layer.defvjp(_first_critic_layer_forward, _first_critic_layer_backward)


def _head(x: jax.Array, matrix: jax.Array, sums: bool = False) -> jax.Array:
    """The fp32 output head (``nn.Dense`` at fp32) on an augmented input, ``[..., k] →
    [..., n]``. ``sums`` (``Layout.head_sums``), from bf16 activations: n products summed
    over k, which XLA fuses with the cast to fp32 into one pass over ``x``, where the dot
    first writes ``x`` in fp32 and then runs an fp32 GEMM whose n (the actor's 2 outputs) is
    too narrow for its tiles (``results/bench_head_sums/``). The same function, summed in
    another order; fp32 activations keep the dot."""
    if not sums or x.dtype == jnp.float32:
        return _dot(x.astype(jnp.float32), matrix)
    x = x.astype(jnp.float32)
    return jnp.stack([jnp.sum(x * matrix[:, j], axis=-1) for j in range(matrix.shape[1])], -1)


def _head_matrix(dense: dict, k_in: int) -> jax.Array:
    return head_matrix(dense["kernel"], dense["bias"], k_in)


def actor_matrices(params: Any, dtype: Any = jnp.float32, align: int = ALIGN) -> list[jax.Array]:
    """The actor's augmented matrices in ``dtype`` (hidden layers, their widths ``padded`` to
    ``align``) and fp32 (the head): what ``actor_forward`` multiplies by; a function of the
    parameters alone, so a caller may build them once for several passes (``agent.learner``'s
    target networks)."""
    p = params["params"]
    n_hidden = sum(name.startswith("hidden_") for name in p)
    k_in, matrices = padded(p["hidden_0"]["kernel"].shape[0] + 1), []
    for i in range(n_hidden):
        layer = p[f"hidden_{i}"]
        matrices.append(layer_matrix([(layer["kernel"], 0)], layer["bias"], k_in, dtype, align))
        k_in = matrices[-1].shape[1]
    return [*matrices, _head_matrix(p["head"], k_in)]


def actor_forward(matrices: list[jax.Array], obs: jax.Array, head_sums: bool = False) -> jax.Array:
    """π(s; φ) → (V, ω) from ``actor_matrices``; ``head_sums``: ``_head``'s ``sums``."""
    x = with_ones(obs, matrices[0].dtype)
    for matrix in matrices[:-1]:
        x = _hidden(x, matrix)
    logits = _head(x, matrices[-1], head_sums)
    return jnp.stack([jax.nn.sigmoid(logits[..., 0]), jnp.tanh(logits[..., 1])], axis=-1)


def actor_apply(params: Any, obs: jax.Array, dtype: Any = jnp.float32) -> jax.Array:
    """``networks.Actor(dtype=dtype).apply(params, obs)``: π(s; φ) → (V, ω)."""
    return actor_forward(actor_matrices(params, dtype), obs)


def _pass_on_signs(n: int, dtype: Any) -> jax.Array:
    """[n, 2n]: input j → columns (+a_j, -a_j)."""
    return jnp.kron(jnp.eye(n, dtype=dtype), jnp.asarray([[1.0, -1.0]], dtype))


def critic_matrices(params: Any, dtype: Any = jnp.float32, align: int = ALIGN) -> list[jax.Array]:
    """The critic's augmented matrices in ``dtype`` (hidden layers) and fp32 (the head), as
    ``actor_matrices``. The first layer passes the action on as ``relu(±a)``; the join
    layer holds ``K_a`` against ``relu(a)`` and ``-K_a`` against ``relu(-a)`` (module
    docstring). Its leaves may carry a leading critic axis under ``jax.vmap``."""
    p = params["params"]
    state = p["state"]
    n_in, width = state["kernel"].shape
    join = p["hidden_0"]
    k_a = join["kernel"]["action"]  # [n_act, out]
    n_act = k_a.shape[0]
    # [[K_s, 0], [0, ±1]]: the state layer, and the action passed on
    first = [(state["kernel"], 0), (_pass_on_signs(n_act, state["kernel"].dtype), width)]
    first_bias = jnp.pad(state["bias"], (0, 2 * n_act))
    matrices = [layer_matrix(first, first_bias, padded(n_in + n_act + 1), dtype, align)]
    signed = jnp.stack([k_a, -k_a], axis=1).reshape(2 * n_act, -1)  # against relu(+a), relu(-a)
    blocks = [(join["kernel"]["state"], 0), (signed, 0)]
    matrices.append(layer_matrix(blocks, join["bias"], matrices[-1].shape[1], dtype, align))
    i = 1
    while f"hidden_{i}" in p:
        layer = p[f"hidden_{i}"]
        k_in = matrices[-1].shape[1]
        matrices.append(layer_matrix([(layer["kernel"], 0)], layer["bias"], k_in, dtype, align))
        i += 1
    return [*matrices, _head_matrix(p["q"], matrices[-1].shape[1])]


def critic_tied_rows(params: Any) -> tuple[int, int, int]:
    """Where ``critic_matrices`` puts the action's kernel twice: (layer 1, its first row, the
    action's size): rows ``first + 2j`` hold ``K_a[j]`` and ``first + 2j + 1`` ``-K_a[j]``,
    after the state layer's outputs."""
    p = params["params"]
    return 1, p["state"]["kernel"].shape[-1], p["hidden_0"]["kernel"]["action"].shape[-2]


def critic_forward(
    matrices: list[jax.Array],
    obs: jax.Array,
    action: jax.Array,
    first_layer_kernel: bool = False,
    head_sums: bool = False,
) -> jax.Array:
    """Q(s, a; θ) from ``critic_matrices``. ``first_layer_kernel``: the first layer's weight
    gradient and ReLU mask in one kernel (``first_critic_layer``), for a batch ``[n,
    ...]`` of its tiles' size; ``head_sums``: ``_head``'s ``sums``; the same function."""
    x = with_ones(jnp.concatenate([obs, action.astype(obs.dtype)], axis=-1), matrices[0].dtype)
    fits = x.ndim == 2 and masked_wgrad.fits(*x.shape, matrices[0].shape[1])
    first = first_critic_layer if first_layer_kernel and fits else _hidden
    x = first(x, matrices[0])  # [h, relu(±a), 1, 0…]
    for matrix in matrices[1:-1]:
        x = _hidden(x, matrix)
    return _head(x, matrices[-1], head_sums)[..., 0]


def critic_apply(
    params: Any, obs: jax.Array, action: jax.Array, dtype: Any = jnp.float32
) -> jax.Array:
    """``networks.Critic(dtype=dtype).apply(params, obs, action)``: Q(s, a; θ)."""
    return critic_forward(critic_matrices(params, dtype), obs, action)
