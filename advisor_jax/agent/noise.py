"""Ornstein–Uhlenbeck exploration noise (Alg. 1 step 13, Alg. A2 step 15).

The paper adds OU noise [54] to the selected action but gives no parameters; ours are
``HParams.ou_theta`` (θ = 0.15, as in the original DDPG paper) and ``HParams.ou_sigma``
(σ = 0.1 in normalised action units, half of DDPG's 0.2, which drove the advisor itself
into obstacles; see ``config.py``). One step of the discrete process (unit
time step, as in DDPG implementations)::

    x_{t+1} = x_t + θ (μ - x_t) + σ ξ_t,    ξ_t ~ N(0, I)

For 0 < θ < 2 it is a stable AR(1) process, x_{t+1} - μ = (1 - θ)(x_t - μ) + σ ξ_t, whose
stationary standard deviation is σ / sqrt(θ (2 - θ)) (tested). The state is reset to 0 at
the start of every episode (``ou_reset``). The trainer adds the returned noise to the
selected action and then clips to the action box.
"""

from __future__ import annotations

import jax
import jax.numpy as jnp
from flax import struct

from advisor_jax.contract import spec


@struct.dataclass
class OUState:
    x: jax.Array  # [..., 2]


def ou_init(shape: tuple[int, ...] = (spec.ACTION_SIZE,)) -> OUState:
    """Zero state of the given shape (e.g. ``(envs, 2)``)."""
    return OUState(x=jnp.zeros(shape, jnp.float32))


def ou_step(
    state: OUState,
    key: jax.Array,
    theta: jax.Array | float,
    sigma: jax.Array | float,
    mu: jax.Array | float = 0.0,
) -> tuple[OUState, jax.Array]:
    """One OU step; returns ``(new state, noise)`` where ``noise`` is the new ``x``."""
    x = state.x + theta * (mu - state.x) + sigma * jax.random.normal(key, state.x.shape)
    return OUState(x=x), x


def ou_reset(state: OUState, done: jax.Array) -> OUState:
    """Zeroes the processes whose episode ended. ``done``: bool/float ``[...]`` (no action axis)."""
    done = jnp.asarray(done).astype(bool)[..., None]  # broadcast over the action axis
    return OUState(x=jnp.where(done, 0.0, state.x))
