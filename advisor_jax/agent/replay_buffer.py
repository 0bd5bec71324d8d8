"""Per-agent replay memory: a fixed-capacity ring buffer (Alg. 1 step 16, Alg. 2 step 6).

Every transition stores the advisor's action a_adv next to the executed action, because
AfP (Alg. 2 steps 11-13) compares Q(s, a_adv) with Q(s, â) at update time, whatever the
selector executed. ``terminal`` is 1.0 only for goal and collision (no bootstrap); a
timeout is a truncation and is stored with ``terminal = 0.0`` so the critic bootstraps
(docs/architecture.md, "Replay").

Outline::

    add(E transitions):  slots = (position + arange(E)) % capacity   # scatter, cost ∝ E
                         position = (position + E) % capacity
                         size = min(size + E, capacity)
    sample(n):           idx ~ U{0, ..., size - 1}^n                 # gather, cost ∝ n

Sampling is uniform with replacement over the valid slots ``[0, size)``; slots are only
ever filled in order, so ``[0, size)`` is exactly the set of written slots. With
``size == 0`` the sample is n copies of slot 0, i.e. the all-zero initial transition: the
trainer never samples before ``size >= cfg.warmup``, so this only keeps the function total
under ``jit`` (no error can be raised on a traced value).

Functions are pure and unbatched; the trainer ``vmap``s them over agents. The capacity is
static (the leading axis of ``data``).
"""

from __future__ import annotations

import jax
import jax.numpy as jnp
from flax import struct

from advisor_jax.contract import spec


@struct.dataclass
class Transition:
    """One or more transitions; every field shares the same leading shape ``[...]``."""

    obs: jax.Array  # [..., 20]
    action: jax.Array  # [..., 2] executed action (after selector, noise, clipping)
    advisor_action: jax.Array  # [..., 2] a_adv, always stored
    reward: jax.Array  # [...]
    next_obs: jax.Array  # [..., 20]
    terminal: jax.Array  # [...] 1.0 = goal/collision (no bootstrap); timeout = 0.0


@struct.dataclass
class ReplayState:
    data: Transition  # leading axis = capacity
    position: jax.Array  # int32, next write slot
    size: jax.Array  # int32, number of valid transitions (<= capacity)


# Trailing (per-transition) shape of each field; the leading axes are free.
_FIELD_SHAPES = {
    "obs": (spec.OBS_SIZE,),
    "action": (spec.ACTION_SIZE,),
    "advisor_action": (spec.ACTION_SIZE,),
    "reward": (),
    "next_obs": (spec.OBS_SIZE,),
    "terminal": (),
}


def _check_static_int(name: str, value) -> int:
    if isinstance(value, bool) or not isinstance(value, int) or value <= 0:
        raise ValueError(f"{name} must be a positive Python int (static), got {value!r}")
    return value


def replay_init(capacity: int) -> ReplayState:
    """An empty buffer of ``capacity`` zero transitions (float32)."""
    capacity = _check_static_int("capacity", capacity)
    data = Transition(
        **{
            name: jnp.zeros((capacity, *shape), jnp.float32)
            for name, shape in _FIELD_SHAPES.items()
        }
    )
    return ReplayState(data=data, position=jnp.int32(0), size=jnp.int32(0))


def _check_batch(batch: Transition, capacity: int) -> int:
    """Shape checks at trace time; returns the number E of transitions in ``batch``."""
    n = None
    for name, trailing in _FIELD_SHAPES.items():
        shape = jnp.shape(getattr(batch, name))
        if len(shape) != 1 + len(trailing) or tuple(shape[1:]) != trailing:
            expected = str(("E", *trailing)).replace("'", "")  # "(E, 20)" or "(E,)"
            raise ValueError(f"replay_add: batch.{name} has shape {shape}; expected {expected}")
        if n is None:
            n = shape[0]
        elif shape[0] != n:
            raise ValueError(
                f"replay_add: batch.{name} has {shape[0]} transitions, batch.obs has {n}"
            )
    if n > capacity:
        # Two writes to one slot in a single scatter have no defined winner.
        raise ValueError(f"replay_add: {n} transitions at once exceed the capacity {capacity}")
    return n


def replay_add(
    state: ReplayState, batch: Transition, valid: jax.Array | None = None
) -> ReplayState:
    """Writes the E transitions of ``batch`` (leading axis E ≤ capacity), oldest overwritten.

    ``valid`` ([E] bool, optional) keeps only the marked transitions, in order; the others
    are dropped (a baseline's offline phase holds the environment: nothing to store).
    """
    capacity = state.data.reward.shape[0]
    n = _check_batch(batch, capacity)
    mode = None
    if valid is None:
        slots = (state.position + jnp.arange(n, dtype=jnp.int32)) % capacity  # [E]
        added = n
    else:
        mode = "drop"
        valid = jnp.broadcast_to(valid, (n,))
        rank = jnp.cumsum(valid.astype(jnp.int32)) - 1  # [E] place among the kept ones
        slots = jnp.where(valid, (state.position + rank) % capacity, capacity)  # out: dropped
        added = jnp.sum(valid, dtype=jnp.int32)
    data = jax.tree.map(
        lambda buf, new: buf.at[slots].set(new.astype(buf.dtype), mode=mode), state.data, batch
    )
    return ReplayState(
        data=data,
        position=((state.position + added) % capacity).astype(jnp.int32),
        size=jnp.minimum(state.size + added, capacity).astype(jnp.int32),
    )


def replay_sample(state: ReplayState, key: jax.Array, batch_size: int) -> Transition:
    """``batch_size`` transitions drawn uniformly, with replacement, from slots ``[0, size)``.

    With ``size == 0`` it returns copies of the zero transition in slot 0 (see module doc).
    """
    batch_size = _check_static_int("batch_size", batch_size)
    idx = jax.random.randint(key, (batch_size,), 0, jnp.maximum(state.size, 1))  # [n]
    return jax.tree.map(lambda buf: buf[idx], state.data)
