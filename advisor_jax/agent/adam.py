"""The learners' Adam, with its moments stored in bf16 for bf16 learners on GPUs.

Adam (Kingma & Ba 2015, Alg. 1), as ``optax.adam``::

    m ← β₁ m + (1 - β₁) g          v ← β₂ v + (1 - β₂) g²
    θ ← θ - α · m̂ / (√v̂ + ε)      m̂ = m / (1 - β₁ᵗ),  v̂ = v / (1 - β₂ᵗ)

Each step computes m and v in fp32 and takes the update from them; only what is *stored*
for the next step may be narrower (``Layout.bf16_first_moment`` / ``bf16_second_moment``,
which ``training.program.network_layout`` turns on for GPUs). A bf16 learner's Adam is a
pass over memory per layer, and every byte of state it need not read and write is time
(``results/bench_bf16_second_moment/``).

* m in bf16 (``mu_dtype``): rounded to nearest, as ``optax.adam`` stores it.
* v in bf16 (``nu_bf16``): rounded *stochastically*. To nearest, v would stop moving: its
  step adds 0.001 g² (β₂ = 0.999), below bf16's resolution (2⁻⁸ of v) whenever g² is near
  v, so v would round back to itself. Rounded up with probability equal to the fraction of
  bf16's step it lies above its lower neighbour, the stored v is v on average
  (``stochastic_bf16``), and its moving average keeps moving.

The stochastic rounding's random bits are a hash of the parameter's fp32 bits (``dither``),
which every step changes: no key to carry, the same in a vmapped population as in a single
run, and equal for parameters of equal magnitude, which the held critics need (their tied
``-K_a`` rows stay the exact negation of the ``+K_a`` rows; ``held_critics``).

The parameters themselves may be bf16 (``apply_updates``): the held critics' matrices of a
bf16 learner on a GPU (``networks.Layout.bf16_critic_weights``, ``held_critics``). Then θ + u
is taken in fp32 and rounded stochastically as v is, its random bits a hash of that sum and
the step's count (``dither``'s salt; v's too, since the parameter may not move): an
update below bf16's resolution (a parameter near 0.03 has steps of 1.2·10⁻⁴; Adam's step is
about the learning rate, 10⁻³ or 10⁻⁴, and the soft update's τ·(θ - θ^T) far less) still
moves the parameter by itself on average, where rounding to nearest would drop it.

Both moments are read back as fp32 (optax's bf16 m is multiplied by β₁ in bf16, 0.8984), and
the stored moments pass an optimization barrier: without it XLA recomputed a steady block's
earlier moments inside later passes, from every earlier gradient, and the passes moved more
bytes, not fewer (``results/bench_bf16_second_moment/``).
"""

from __future__ import annotations

from typing import Any

import jax
import jax.numpy as jnp
import optax


def dither(values: jax.Array, salt: jax.Array | int | None = None) -> jax.Array:
    """16 random bits per entry (uint32 in [0, 2¹⁶)) from fp32 ``values``, the parameters: the
    top half of ``|values|``' bits times ⌊2³²/φ⌋ (Knuth's multiplicative hash). An Adam step
    moves an fp32 parameter by thousands of units in its last place, by amounts that differ
    from entry to entry and step to step, so the draws are new at every step and unrelated to
    v's (the hash spreads a difference of one unit over the top bits; only a shift shared by
    all entries would shift all their draws alike). Equal for ``±x``; the pass reads the
    parameters anyway.

    With a ``salt`` (the step's count): ``|values|``' bits mixed with the salt's by an integer
    hash (``_mix``). Needed where the values repeat from step to step: a bf16 parameter stays
    put until its rounding moves it, and θ + u repeats while Adam's step u does; unsalted, the
    same draw would round it the same way at every step (stuck, or a whole bf16 step each
    time)."""
    magnitude = jax.lax.bitcast_convert_type(jnp.abs(values.astype(jnp.float32)), jnp.uint32)
    if salt is None:
        return (magnitude * jnp.uint32(0x9E3779B9)) >> 16
    salted = magnitude ^ _mix(jnp.asarray(salt).astype(jnp.uint32) + jnp.uint32(0x9E3779B9))
    return _mix(salted) >> 16


def _mix(h: jax.Array) -> jax.Array:
    """A 32-bit integer hash (Wellons' "lowbias32": xor-shifts and two odd multipliers), each
    input bit flipping about half of the output bits."""
    h = (h ^ (h >> 16)) * jnp.uint32(0x7FEB352D)
    h = (h ^ (h >> 15)) * jnp.uint32(0x846CA68B)
    return h ^ (h >> 16)


def stochastic_bf16(x: jax.Array, bits: jax.Array) -> jax.Array:
    """fp32 ``x`` rounded to bf16, up or down with the probabilities that make the rounding
    exact on average, given ``bits`` uniform in [0, 2¹⁶): the 16 bits bf16 drops are added to
    ``bits`` and the sum carries into the kept bits with probability (dropped bits) / 2¹⁶.
    Values that are not finite round to nearest (the sum could carry a NaN into ±inf)."""
    raw = jax.lax.bitcast_convert_type(x, jnp.uint32)
    kept = ((raw + bits) >> 16).astype(jnp.uint16)
    rounded = jax.lax.bitcast_convert_type(kept, jnp.bfloat16)
    return jnp.where(jnp.isfinite(x), rounded, x.astype(jnp.bfloat16))


def rounded_like(x: jax.Array, like: jax.Array, salt: jax.Array | int) -> jax.Array:
    """fp32 ``x`` in ``like``'s dtype: bf16 stochastically rounded (``stochastic_bf16``, its
    bits ``dither(x, salt)``; ``salt``: the step's count), so that a bf16 parameter moves by
    its fp32 update on average; anything else as ``astype`` casts it."""
    if like.dtype != jnp.bfloat16:
        return x.astype(like.dtype)
    return stochastic_bf16(x, dither(x, salt))


def apply_updates(params: Any, updates: Any, salt: jax.Array | int) -> Any:
    """``optax.apply_updates`` (θ + u, in θ's dtype), each sum taken in fp32 and bf16
    parameters rounded stochastically (``rounded_like``, ``salt`` the step's count): the
    same for fp32 parameters."""
    return jax.tree.map(
        lambda p, u: rounded_like(p.astype(jnp.float32) + u.astype(jnp.float32), p, salt),
        params,
        updates,
    )


def scale_by_adam(
    b1: float = 0.9,
    b2: float = 0.999,
    eps: float = 1e-8,
    mu_dtype: Any = None,
    nu_bf16: bool = False,
) -> optax.GradientTransformation:
    """``optax.scale_by_adam`` (its state, ``optax.ScaleByAdamState``, and its arithmetic: the
    same updates bit for bit when ``nu_bf16`` is off), with v stored in bf16 by stochastic
    rounding when ``nu_bf16`` is on: the step is the one fp32 v gives, only the stored v is
    rounded. Needs the parameters (``update(g, state, params)``): their bits hash to the
    rounding's random bits (``dither``)."""
    inner = optax.scale_by_adam(b1, b2, eps, mu_dtype=mu_dtype)
    if not nu_bf16:
        return inner

    def init(params):
        state = inner.init(params)
        return state._replace(nu=jax.tree.map(lambda p: jnp.zeros(p.shape, jnp.bfloat16), params))

    def update(updates, state, params=None):
        if params is None:
            raise ValueError("Adam with a bf16 second moment needs the parameters")
        count = optax.safe_increment(state.count)
        # optax.scale_by_adam's expressions, the stored moments read as fp32: a bf16 b2 · v
        # would round back to v, and optax's bf16 b1 · m multiplies by b1 rounded to bf16
        mu = jax.tree.map(lambda g, m: (1 - b1) * g + b1 * m.astype(jnp.float32), updates,
                          state.mu)  # fmt: skip
        nu = jax.tree.map(lambda g, v: (1 - b2) * g**2 + b2 * v.astype(jnp.float32), updates,
                          state.nu)  # fmt: skip
        mu_hat = jax.tree.map(lambda m: m / (1 - b1**count).astype(m.dtype), mu)
        nu_hat = jax.tree.map(lambda v: v / (1 - b2**count).astype(v.dtype), nu)
        steps = jax.tree.map(lambda m, v: m / (jnp.sqrt(v) + eps), mu_hat, nu_hat)
        if mu_dtype is not None:
            mu = jax.tree.map(lambda m: m.astype(mu_dtype), mu)
        # a bf16 parameter may not move between steps: its draws need the count (dither)
        salt = lambda p: count if p.dtype == jnp.bfloat16 else None  # noqa: E731
        nu = jax.tree.map(lambda v, p: stochastic_bf16(v, dither(p, salt(p))), nu, params)
        # Stored, not recomputed: without the barrier XLA fused the moments' moving averages
        # of a steady block's earlier updates into the later updates' passes, which then
        # read every earlier gradient again instead of the stored moments.
        mu, nu = jax.lax.optimization_barrier((mu, nu))
        return steps, optax.ScaleByAdamState(count, mu, nu)

    return optax.GradientTransformation(init, update)


def adam(
    learning_rate: jax.Array | float, mu_dtype: Any = None, nu_bf16: bool = False
) -> optax.GradientTransformation:
    """``optax.adam(learning_rate, mu_dtype=mu_dtype)`` (the same state tree: Adam's, then the
    learning rate's), with v stored in bf16 when ``nu_bf16`` (``scale_by_adam``)."""
    if not nu_bf16:
        return optax.adam(learning_rate, mu_dtype=mu_dtype)
    return optax.chain(
        scale_by_adam(mu_dtype=mu_dtype, nu_bf16=True), optax.scale_by_learning_rate(learning_rate)
    )
