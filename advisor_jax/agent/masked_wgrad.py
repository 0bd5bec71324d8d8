"""The critic's first hidden layer with its weight gradient and ReLU mask in one kernel.

In the critic step (the gradient of Eq. 5) the first hidden layer ``Y = relu(X @ W)``
(``gemm_layers``: X the augmented (s, a) input, ``[n, 24]`` at the paper's sizes, W
``[24, 1008]``) has one job in the backward pass: the weight gradient

    dW = Xᵀ · where(Y > 0, dY, 0)

since X is replayed data and its gradient unused. XLA runs the ReLU's mask as a pass of its
own, which reads Y and dY and writes the masked gradient, and then a GEMM that reads that
again: 0.50 ms of a 128-agent bf16 update on an H100 for the mask alone, 1.01 ms in fp32
(``results/bench_learner_gemm_layers/profile_h100/``). ``weight_gradient`` reads Y and dY
once, masks them in registers and accumulates Xᵀ·(masked) on the tensor cores: a Pallas
kernel (its Triton backend on GPUs; ``interpret`` elsewhere, for the tests).

Measured on an H100 (``results/bench_first_layer_kernel/``): 0.394 ms per 128-agent bf16
update, at the device's copy rate, and the learner 1.03× (bf16) / 1.04× (fp32) faster, with
the same updates.

Half of those bytes are Y, read for its sign alone. In bf16 the products of X's and W's
entries are exact in fp32, so ``X @ W > 0`` computed again in the kernel, from X's 24 columns
that it reads anyway and W's tile, is the forward's mask up to the fp32 sum's order (a sign
can differ only where the pre-activation is within a few fp32 units of 0).
``weight_gradient_from_input`` takes W for Y and reads dY alone; ``gemm_layers`` uses it for
bf16 matrices. fp32 layers, whose forward GEMM may round its inputs to TF32 on a GPU, keep Y.

Under ``jax.vmap`` (the population's agents, the twin critics) the kernel runs once over the
stacked batch, inside a ``custom_partitioning`` that keeps the leading axis's sharding: a
population sharded along its agents (the outermost vmap, so the stacked axis's major part)
runs each device's agents' kernels on that device, no collective between them
(``weight_gradient``; ``results/bench_multigpu/``).

``gemm_layers.first_critic_layer`` is the layer with that backward (``jax.custom_vjp``).
Where the input's gradient is wanted (the actor step's ∇_a Q of Eq. 2) it is computed as
before, from the masked gradient, and XLA drops whichever of the two gradients nobody reads.

A program sums the rows of one column tile. Few layers (fewer than 8 agents' twin critics on
a device) would leave most of a GPU idle, 16 programs at 1 agent, so their rows are split
over several programs whose fp32 partial sums one small XLA reduction adds (``row_splits``,
``results/bench_first_layer_kernel/``, "Few agents": the 1-agent step 1.02-1.04× on an H100).

The kernel's tiles never leave the arrays: the last tile of the batch (rows) starts at
``n - ROWS`` and zeroes the rows an earlier tile summed (1,000 has no power-of-two divisor
≥ 16, the tensor cores' least), and the last tile of the columns starts at ``m - COLS``, so
that two programs write the same values to the columns they share.
"""

from __future__ import annotations

import functools

import jax
import jax.numpy as jnp
from jax.custom_batching import custom_vmap
from jax.experimental import pallas as pl
from jax.experimental.custom_partitioning import custom_partitioning
from jax.experimental.pallas import triton as pl_triton
from jax.sharding import NamedSharding, PartitionSpec

ROWS = 32
"""Batch rows per step of the kernel's reduction."""
COLS = 128
"""Output columns per program."""
PROGRAMS = 128
"""The programs a kernel aims for when its layers are few (``row_splits``): about one per
streaming multiprocessor of an H100 (132)."""
MIN_TILE = 16
"""The tensor cores' least dimension: smaller layers keep XLA's mask and GEMM."""
KERNEL_NAME = "masked_weight_gradient"
"""The kernel's name in compiled HLO and in device traces."""


def _pow2_floor(n: int) -> int:
    return 1 << (n.bit_length() - 1)


def _kernel(x_ref, y_ref, g_ref, out_ref, *, rows: int, cols: int, splits: int, from_input: bool):
    n, m = g_ref.shape
    col0 = jnp.minimum(pl.program_id(0) * cols, m - cols)
    first, last = 0, pl.cdiv(n, rows)  # row tiles; with splits, this program's share
    if splits > 1:
        steps = pl.cdiv(last, splits)
        first = pl.program_id(1) * steps
        last = jnp.minimum(first + steps, last)
    if from_input:  # y_ref holds the layer's matrix: its columns of this tile, read once
        w = y_ref[:, pl.ds(col0, cols)]

    def step(i, acc):
        start = i * rows
        row0 = jnp.minimum(start, n - rows)
        fresh = (row0 + jnp.arange(rows)) >= start  # rows no earlier step summed
        x = jnp.where(fresh[:, None], x_ref[pl.ds(row0, rows), :], 0)
        g = g_ref[pl.ds(row0, rows), pl.ds(col0, cols)]
        if from_input:  # the forward's pre-activation again, from x's few columns
            kept = pl_triton.dot(x, w) > 0
        else:
            kept = y_ref[pl.ds(row0, rows), pl.ds(col0, cols)] > 0
        masked = jnp.where(kept, g, jnp.zeros((), g.dtype))
        return acc + pl_triton.dot(x, masked, trans_a=True)

    k = x_ref.shape[1]
    acc = jax.lax.fori_loop(first, last, step, jnp.zeros((k, cols), jnp.float32))
    if splits == 1:  # the gradient itself
        out_ref[:, pl.ds(col0, cols)] = acc.astype(out_ref.dtype)
    else:  # this program's fp32 partial sum
        out_ref[pl.ds(pl.program_id(1), 1), :, pl.ds(col0, cols)] = acc[None]


def fits(n: int, k: int, m: int) -> bool:
    """Whether a layer of batch ``n``, input width ``k`` and output width ``m`` has the
    kernel's tiles (at least ``MIN_TILE`` in each dimension)."""
    return min(n, k, m) >= MIN_TILE


def row_splits(batch: int, n: int, m: int) -> int:
    """How many programs share the batch rows of each column tile (split-K) when ``batch``
    layers of batch ``n`` and output width ``m`` run as one kernel: enough, in powers of two,
    for about ``PROGRAMS`` programs, at most one per row tile. 1 from 16 layers up (8 agents'
    twin critics at the paper's sizes), where the column tiles alone fill a GPU."""
    col_tiles = pl.cdiv(m, min(COLS, _pow2_floor(m)))
    row_tiles = pl.cdiv(n, min(ROWS, _pow2_floor(n)))
    splits = 1
    while batch * col_tiles * splits * 2 <= PROGRAMS and splits * 2 <= row_tiles:
        splits *= 2
    return splits


def kernel(
    x: jax.Array,
    y: jax.Array,
    g: jax.Array,
    interpret: bool | None = None,
    splits: int = 1,
    from_input: bool = False,
):
    """``xᵀ · where(y > 0, g, 0)`` → ``[k, m]`` in ``g``'s dtype (fp32 accumulation), for
    ``x [n, k]``, ``y`` and ``g`` ``[n, m]``: one Pallas kernel. ``from_input``: ``y`` is the
    layer's matrix ``[k, m]`` instead, and the kernel takes the mask from ``x @ y > 0``, the
    forward's pre-activation computed again (``weight_gradient_from_input``). ``interpret``:
    run it in Pallas's interpreter (default: off a GPU). ``splits`` (``row_splits``):
    programs that share each column tile's rows, each writing an fp32 partial sum that one
    small XLA reduction adds before the rounding to ``g``'s dtype. ``jax.vmap`` batches it
    into a grid axis of the same kernel, a custom call XLA's partitioner cannot split: batch
    with ``weight_gradient`` instead."""
    (n, k), m = x.shape, g.shape[1]
    if not fits(n, k, m):
        raise ValueError(f"masked_wgrad: [{n}, {k}] x [{n}, {m}] has a side below {MIN_TILE}")
    if interpret is None:
        interpret = jax.default_backend() != "gpu"
    k_tile = pl.next_power_of_2(k)  # a tile's sides are powers of two: x gets zero columns
    x = jnp.pad(x.astype(g.dtype), ((0, 0), (0, k_tile - k)))
    if from_input:  # and the matrix zero rows against them
        y = jnp.pad(y.astype(g.dtype), ((0, k_tile - k), (0, 0)))
    rows, cols = min(ROWS, _pow2_floor(n)), min(COLS, _pow2_floor(m))
    shape = (k_tile, m) if splits == 1 else (splits, k_tile, m)
    out = pl.pallas_call(
        functools.partial(_kernel, rows=rows, cols=cols, splits=splits, from_input=from_input),
        out_shape=jax.ShapeDtypeStruct(shape, g.dtype if splits == 1 else jnp.float32),
        grid=(pl.cdiv(m, cols),) if splits == 1 else (pl.cdiv(m, cols), splits),
        interpret=interpret,
        name=KERNEL_NAME,
    )(x, y, g)
    if splits > 1:
        out = out.sum(axis=0).astype(g.dtype)
    return out[:k]


def _agents_only(sharding: NamedSharding, ndim: int) -> NamedSharding:
    """``sharding`` on the leading (agent) axis, the other ``ndim - 1`` axes whole."""
    leading = tuple(sharding.spec)[:1] or (None,)
    return NamedSharding(sharding.mesh, PartitionSpec(*leading, *([None] * (ndim - 1))))


def _broadcast(size: int, in_batched, args):
    """``args`` each with a leading axis of ``size``: the unbatched ones broadcast."""
    pairs = zip(args, in_batched, strict=True)
    return [a if batched else jnp.broadcast_to(a, (size, *a.shape)) for a, batched in pairs]


def _batched_kernel(from_input: bool):
    """``kernel`` (with ``from_input``) as a function of one layer whose ``jax.vmap``, once or
    nested, is one kernel over the stacked batch that a population sharded along its agents
    splits by device."""

    def kernels(x: jax.Array, y: jax.Array, g: jax.Array) -> jax.Array:
        """``kernel`` over a leading batch axis, ``[b, n, k]`` → ``[b, k, m]``, its rows split
        as ``row_splits`` gives for this batch."""
        (b, n, _), m = x.shape, g.shape[-1]
        splits = row_splits(b, n, m)
        one = functools.partial(kernel, splits=splits, from_input=from_input)
        return jax.vmap(one)(x, y, g)

    @custom_partitioning
    def split_by_agents(x: jax.Array, y: jax.Array, g: jax.Array) -> jax.Array:
        """``kernels``. Over several devices XLA's partitioner gives each device the kernel of
        its own rows of the batch axis (its agents), where the kernel's custom call alone would
        be gathered whole onto every device."""
        return kernels(x, y, g)

    def partition(mesh, arg_shapes, result_shape):
        sharding = _agents_only(arg_shapes[0].sharding, 3)
        return mesh, kernels, sharding, (sharding,) * 3

    def infer_sharding(mesh, arg_shapes, result_shape):
        return _agents_only(arg_shapes[0].sharding, 3)

    split_by_agents.def_partition(
        partition,
        infer_sharding_from_operands=infer_sharding,
        sharding_rule="b n k, b k m, b n m -> b k m"
        if from_input
        else "b n k, b n m, b n m -> b k m",
        need_replication_factors=("n", "k", "m"),
    )

    @custom_vmap
    def stacked(x: jax.Array, y: jax.Array, g: jax.Array) -> jax.Array:
        """``split_by_agents``, whose ``jax.vmap`` merges the new axis into the batch (leading,
        so the agents stay its major part and its sharding)."""
        return split_by_agents(x, y, g)

    @stacked.def_vmap
    def stacked_vmap(size, in_batched, x, y, g):
        x, y, g = _broadcast(size, in_batched, (x, y, g))
        out = stacked(*(a.reshape(-1, *a.shape[2:]) for a in (x, y, g)))
        return out.reshape(size, -1, *out.shape[1:]), True

    @custom_vmap
    def one_layer(x: jax.Array, y: jax.Array, g: jax.Array) -> jax.Array:
        return kernels(x[None], y[None], g[None])[0]

    @one_layer.def_vmap
    def one_layer_vmap(size, in_batched, x, y, g):
        return stacked(*_broadcast(size, in_batched, (x, y, g))), True

    return one_layer


weight_gradient = _batched_kernel(from_input=False)
"""``weight_gradient(x, y, g)``: ``xᵀ · where(y > 0, g, 0)`` (``kernel``), ``y`` the layer's
output; vmapped, one kernel that a population sharded along its agents splits by device."""

weight_gradient_from_input = _batched_kernel(from_input=True)
"""``weight_gradient_from_input(x, w, g)``: ``xᵀ · where(x @ w > 0, g, 0)``, the mask from the
layer's input ``x`` and matrix ``w`` (``kernel``'s ``from_input``), so that the kernel reads
``g`` and not the layer's output; vmapped as ``weight_gradient``."""
