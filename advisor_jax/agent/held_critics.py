"""The twin critics held through a training chunk as the matrices their GEMM layers read.

With each hidden layer one GEMM (``gemm_layers``) the critics multiply by augmented matrices
built from the flax parameters: every critic step read the fp32 parameters and wrote the
matrices again (the "matrix build", in bf16 with the cast; in fp32 a copy), and the
gradient came back through the build's transpose. Held, the fp32 augmented matrices *are*
the parameters θ and θ^T for the length of a chunk (``Learner.hold`` at its start,
``release`` at its end, as the target networks are held): Adam and the soft update (Eqs. 5-7)
work on them directly, and in bf16 Adam's pass also writes the bf16 copy that the next
step's GEMMs read. No build remains in the loop. With ``hold``'s ``in_dtype`` (a GPU's bf16
learners, ``networks.Layout.bf16_critic_weights``) the hidden matrices are held in bf16 only:
no fp32 master and no copy, each update rounded stochastically (``adam.apply_updates``,
``soft_update``), so that Adam's pass moves 14 bytes per parameter instead of 20.

The same updates as the flax parameters get, entry by entry:

* An entry that is structure, not a parameter (zero padding, the ones column that carries
  the bias, the first layer's ±1 passing the action on), gets a zero gradient
  (``gradient``: a mask of the rows and columns that hold parameters), so Adam's moments
  stay 0 there and its update is 0: the entry never moves.
* The join layer holds the action's kernel K_a twice, as ``+K_a`` against ``relu(a)`` and
  ``-K_a`` against ``relu(-a)`` (``gemm_layers``). Its gradient is ``g₊ - g₋`` (the
  build's transpose); held, the ``+`` row gets ``g₊ - g₋`` and the ``-`` row ``g₋ - g₊``,
  exactly its negative. Adam and the soft update commute with negation in IEEE arithmetic,
  so the ``-`` rows stay exactly the negated ``+`` rows.
* Every other entry gets the gradient the flax leaf gets, in the same arithmetic.

So held or not, the parameters and Adam's moments get the same update rule entry by entry,
and the results agree to rounding, not bit for bit: given the flax tree, XLA computes some
of its gradient's entries through the slices (the tied rows, the head's bias) with their own
sums (``tests/agent/test_held_critics.py``). The stored state (a chunk's input and output, a
checkpoint) is the flax tree either way. The acting critic of Eq. (1)'s selector reads the
held fp32 matrices (``q_values``) instead of the flax modules: the same function, summed in
another order (the bias inside the GEMM). ``training.program.holds_critics`` decides where
a chunk holds them.
"""

from __future__ import annotations

from collections.abc import Callable
from functools import partial
from typing import Any, NamedTuple

import jax
import jax.numpy as jnp
import numpy as np
import optax

from advisor_jax.agent import adam, gemm_layers, update_rules
from advisor_jax.agent.networks import apply_critics


class HeldCritics(NamedTuple):
    """θ, θ^T and Adam's state of θ as fp32 augmented matrices (lists, one ``[n_critics, k,
    n]`` array per layer), and the copies in the compute dtype that the GEMMs read (None in
    fp32, where they read the parameters)."""

    online: list[jax.Array]
    target: list[jax.Array]
    opt: Any
    online_copy: list[jax.Array] | None
    target_copy: list[jax.Array] | None

    def online_nets(self) -> list[jax.Array]:
        """What the online critics' GEMMs read."""
        return _read(self.online, self.online_copy)

    def target_nets(self) -> list[jax.Array]:
        """What the target critics' GEMMs read."""
        return _read(self.target, self.target_copy)


def _read(matrices: list[jax.Array], hidden_copies: list[jax.Array] | None) -> list[jax.Array]:
    """The hidden layers' copies and the fp32 head (``gemm_layers.critic_matrices``' dtypes)."""
    return matrices if hidden_copies is None else [*hidden_copies, matrices[-1]]


class Structure(NamedTuple):
    """Which entries of each augmented matrix are parameters: those in a row of ``rows`` and a
    column of ``cols`` (static bool vectors per layer); ``tied``: (layer, first row, pairs)
    of the join layer's interleaved ``(+K_a, -K_a)`` rows; ``align``: the hidden widths'
    (``gemm_layers.critic_matrices``' ``align``)."""

    rows: tuple[np.ndarray, ...]
    cols: tuple[np.ndarray, ...]
    tied: tuple[int, int, int]
    align: int = gemm_layers.ALIGN

    def mask(self, layer: int) -> np.ndarray:
        return self.rows[layer][:, None] & self.cols[layer][None, :]

    def minus_rows(self, layer: int) -> np.ndarray:
        """Bool per row: the ``-K_a`` rows (the tied copies)."""
        out = np.zeros(self.rows[layer].shape, bool)
        tied_layer, first, pairs = self.tied
        if layer == tied_layer:
            out[first + 1 : first + 2 * pairs : 2] = True
        return out


def structure(critic_params: Any, align: int = gemm_layers.ALIGN) -> Structure:
    """The ``Structure`` of one critic's matrices (``gemm_layers.critic_matrices`` at ``align``)
    for a params tree of its shapes (no critic axis; arrays or ``jax.ShapeDtypeStruct``): an
    entry is a parameter where the matrices built from all-ones and all-zeros parameters
    differ."""
    with jax.ensure_compile_time_eval():
        ones, zeros = (
            jax.tree.map(lambda s, v=v: jnp.full(s.shape, v, jnp.float32), critic_params)
            for v in (1.0, 0.0)
        )
        built = [gemm_layers.critic_matrices(p, jnp.float32, align) for p in (ones, zeros)]
        differs = [np.asarray(a) != np.asarray(b) for a, b in zip(*built, strict=True)]
    rows = tuple(d.any(axis=1) for d in differs)
    cols = tuple(d.any(axis=0) for d in differs)
    for d, r, c in zip(differs, rows, cols, strict=True):
        if not np.array_equal(d, r[:, None] & c[None, :]):
            raise ValueError("a critic matrix's parameters are not a block of rows × columns")
    tied = gemm_layers.critic_tied_rows(critic_params)
    layer, first, pairs = tied
    signs = np.asarray(built[0][layer] - built[1][layer])[first : first + 2 * pairs]
    if not (np.all(signs[0::2][:, cols[layer]] == 1) and np.all(signs[1::2][:, cols[layer]] == -1)):
        raise ValueError(f"rows {first}.. of critic layer {layer} are not (+K_a, -K_a) pairs")
    return Structure(rows, cols, tied, align)


def _masked(matrices: list[jax.Array], s: Structure) -> list[jax.Array]:
    return [jnp.where(s.mask(i), m, jnp.zeros((), m.dtype)) for i, m in enumerate(matrices)]


def _build(critics: Any, s: Structure) -> list[jax.Array]:
    """fp32 augmented matrices of critics stacked on a leading axis (values placed exactly)."""
    return jax.vmap(partial(gemm_layers.critic_matrices, dtype=jnp.float32, align=s.align))(critics)


def _adam_states(opt_state: Any, convert: Callable[[Any, str], Any]) -> Any:
    """``opt_state`` with the moments of every ``optax.ScaleByAdamState`` converted
    (``convert(tree, "mu" | "nu")``); the count and the rest unchanged."""

    def one(s):
        if isinstance(s, optax.ScaleByAdamState):
            return s._replace(mu=convert(s.mu, "mu"), nu=convert(s.nu, "nu"))
        return s

    is_adam = lambda s: isinstance(s, optax.ScaleByAdamState)  # noqa: E731
    return jax.tree.map(one, opt_state, is_leaf=is_adam)


def copies(matrices: list[jax.Array], dtype: Any) -> list[jax.Array] | None:
    """The hidden layers' matrices in the compute ``dtype``, as ``gemm_layers.critic_matrices``
    builds them (the head stays fp32); None where the GEMMs read the matrices themselves:
    fp32, or hidden matrices held in ``dtype`` already (``hold``'s ``in_dtype``)."""
    if jnp.dtype(dtype) == jnp.float32 or matrices[0].dtype == jnp.dtype(dtype):
        return None
    return [m.astype(dtype) for m in matrices[:-1]]


def hold(
    critic: Any,
    target_critic: Any,
    critic_opt: Any,
    s: Structure,
    dtype: Any,
    in_dtype: bool = False,
) -> HeldCritics:
    """The flax parameters θ, θ^T (leading critic axis) and their Adam state, held as
    matrices. Adam's moments are 0 on structure; ν, like a square, is positive on the
    ``-K_a`` rows (μ, like the gradient, negative). ``in_dtype``: the hidden matrices held in
    the compute ``dtype`` itself (rounded to nearest, exact for parameters a chunk held so),
    no fp32 master and no copy; the updates round them stochastically
    (``adam.apply_updates``, ``soft_update``)."""

    def moments(tree, name):
        dtype_of = jax.tree.leaves(tree)[0].dtype
        built = _masked(_build(tree, s), s)
        built = [jnp.abs(m) for m in built] if name == "nu" else built
        return [m.astype(dtype_of) for m in built]

    online, target = _build(critic, s), _build(target_critic, s)
    opt = _adam_states(critic_opt, moments)
    if in_dtype:  # the hidden matrices in ``dtype``, the head as it is
        online, target = ([*(x.astype(dtype) for x in m[:-1]), m[-1]] for m in (online, target))
    return HeldCritics(online, target, opt, copies(online, dtype), copies(target, dtype))


def soft_update(
    target: list[jax.Array], online: list[jax.Array], tau, salt: jax.Array | int
) -> list[jax.Array]:
    """Eqs. (6), (7) on the held matrices (``update_rules.soft_update``) in fp32, bf16
    matrices rounded stochastically (``adam.rounded_like``; ``salt``: the soft update's
    count). Structure stays exact: τ·1 + (1 - τ)·1 rounds to 1 in fp32 (and 0 to 0), which
    bf16 holds; ``±`` rows alike."""
    f32 = lambda ms: [m.astype(jnp.float32) for m in ms]  # noqa: E731
    mixed = update_rules.soft_update(f32(target), f32(online), tau)
    return [adam.rounded_like(x, t, salt) for x, t in zip(mixed, target, strict=True)]


def _unbuild(matrices: list[jax.Array], template: Any, s: Structure) -> Any:
    """The fp32 flax tree the matrices were built from: the build's transpose (slices,
    exact) of the matrices without their ``-K_a`` rows."""
    kept = [
        jnp.where(s.minus_rows(i)[:, None], 0.0, m.astype(jnp.float32))
        for i, m in enumerate(matrices)
    ]
    zeros = jax.tree.map(lambda x: jnp.zeros(x.shape, jnp.float32), template)
    _, pullback = jax.vjp(lambda critics: _build(critics, s), zeros)
    return pullback(kept)[0]


def release(held: HeldCritics, template: Any, s: Structure) -> tuple[Any, Any, Any]:
    """(θ, θ^T, Adam's state) as the flax trees ``hold`` took; ``template``: θ's tree or its
    shapes (``jax.ShapeDtypeStruct``s)."""

    def moments(matrices, name):
        dtype_of = matrices[0].dtype
        return jax.tree.map(lambda x: x.astype(dtype_of), _unbuild(matrices, template, s))

    critic = _unbuild(held.online, template, s)
    target = _unbuild(held.target, template, s)
    return critic, target, _adam_states(held.opt, moments)


def gradient(d_nets: list[jax.Array], s: Structure) -> list[jax.Array]:
    """The held parameters' fp32 gradient from the loss's gradient with respect to what the
    GEMMs read: 0 on structure, ``±(g₊ - g₋)`` on the tied rows (module docstring). One
    elementwise expression per layer, for XLA to fuse into Adam's pass."""
    layer, first, pairs = s.tied
    out = []
    for i, d in enumerate(d_nets):
        g = d.astype(jnp.float32)
        if i == layer:
            block = g[..., first : first + 2 * pairs, :]
            swapped = jnp.flip(block.reshape(*block.shape[:-2], pairs, 2, -1), -2)
            widths = [(0, 0)] * (g.ndim - 2) + [(first, g.shape[-2] - first - 2 * pairs), (0, 0)]
            g = g - jnp.pad(swapped.reshape(block.shape), widths)
        out.append(g)
    return _masked(out, s)


def _sum_of_squares(g: jax.Array) -> jax.Array:
    """Σ g², summed along its rows first: a reduction over the last axis (rows of a matrix's
    width), the one XLA emits in Adam's pass over the matrix. Summed whole, XLA splits the
    sum over a layer's entries into factors of their count, and at the paper's [504, 608]
    an odd factor (2 · 504 · 608 = 512 · 1197 for the twin critics): that pass, Adam's and
    the sum's, then read memory at about 0.6 of the bandwidth of its neighbours
    (``results/bench_held_critics/``). The barrier keeps XLA from merging the two sums
    back into one."""
    rows = jnp.sum(jnp.square(g), axis=-1)
    return jnp.sum(jax.lax.optimization_barrier(rows))


def global_norm(grads: list[jax.Array], s: Structure) -> jax.Array:
    """``optax.global_norm`` of the flax tree's gradient, from ``gradient``'s: K_a counted once.
    The sum of squares reads what Adam reads (so that XLA can sum it in Adam's pass, row by
    row: ``_sum_of_squares``); the ``-K_a`` rows' share, a few rows, comes off after (at most
    half the total; clamped at 0 all the same, since a NaN norm would mark the agent
    diverged)."""
    layer, first, pairs = s.tied
    minus = grads[layer][..., first + 1 : first + 2 * pairs : 2, :]
    total = sum(_sum_of_squares(g) for g in grads) - jnp.sum(jnp.square(minus))
    return jnp.sqrt(jnp.maximum(total, 0.0))


def q_values(held: HeldCritics, obs: jax.Array, action: jax.Array, per_critic: bool) -> jax.Array:
    """Q of every critic, ``[n_critics, ...]``, at fp32 from the held parameters (acting;
    matrices held in bf16 read as fp32)."""
    online = [m.astype(jnp.float32) for m in held.online]
    return apply_critics(gemm_layers.critic_forward, online, obs, action, per_critic)
