"""The advisor's quality as hyperparameters: any advisor made worse by sweepable knobs.

The paper asks how the advisor's quality shapes what the agents learn. These knobs turn one
advisor (the rule, a user's function, a trained policy; ``advisors.py``) into a family of
worse ones whose every member is a grid point of the same compiled population
(``--grid advisor_random=0,0.2,0.4``). Per step and environment, for knobs q::

    seen  = obs with P_i := 1 (no hit)  where sensor i lies in the blind sector
                                        (|direction_i| < q.advisor_blind / 2, straight ahead)
                                        or P_i >= q.advisor_range
    now   = clip(advisor(params, seen), action box)
    a     = the ``now`` of q.advisor_delay steps ago in this episode (the first step's
            before the episode had that many)
    a     = a + N(0, q.advisor_noise²) per dimension            (only where the noise > 0)
    a     = uniform in the action box with probability q.advisor_random
    a_adv = clip(a, action box)

Every knob at its default (0, and the full 1 m range) leaves the advisor's action exactly as
it was (tested bit for bit), and its random draws come from a key of its own
(``ADVISOR_STREAM`` folded into the step's key), so the RNG streams of everything else are
those of a run without the knobs. Sensor directions are the sonar ring's
(``contract.spec.SONAR_DIRECTIONS_DEG``; the lidar zones of the physical arena are in the
same order, their centres within 12° of them). A delay needs what the advisor proposed on
the last steps: ``AdvisorMemory`` (at most ``MAX_DELAY`` steps), restarted with each episode.
"""

from __future__ import annotations

from collections.abc import Callable
from typing import Any

import jax
import jax.numpy as jnp
import numpy as np
from flax import struct

from advisor_jax.agent.settings import flat_items, hparam
from advisor_jax.contract import spec

MAX_DELAY = 10
"""The longest reaction delay, in control steps (0.5 s at dt = 0.05 s)."""

ADVISOR_STREAM = 0x5AD
"""Folded into a step's key for the advisor's own draws (noise, random actions)."""

_DIRECTIONS = np.abs(np.asarray(spec.SONAR_DIRECTIONS_DEG, np.float32))  # [16] degrees
_LOW = np.asarray(spec.ACTION_LOW, np.float32)
_HIGH = np.asarray(spec.ACTION_HIGH, np.float32)


@struct.dataclass
class AdvisorQuality:
    """The advisor's quality knobs (every one a vmappable hyperparameter; 0 = as it is)."""

    advisor_noise: float = hparam(
        0.0, "σ of Gaussian noise added to the advisor's action (normalised units)", low=0.0
    )
    advisor_random: float = hparam(
        0.0, "probability per step that the advisor acts uniformly at random", low=0.0,
        high=1.0, high_closed=True,
    )  # fmt: skip
    advisor_blind: float = hparam(
        0.0, "width (deg) of a sector straight ahead in which the advisor sees nothing",
        low=0.0, high=360.0, high_closed=True,
    )  # fmt: skip
    advisor_range: float = hparam(
        spec.MAX_RANGE, "the advisor's sensor range (m): it reads no hit at or beyond it",
        low=0.0, high=spec.MAX_RANGE, low_closed=False, high_closed=True,
    )  # fmt: skip
    advisor_delay: float = hparam(
        0.0, "reaction delay (control steps): the advisor acts on what it saw that many "
        "steps ago", low=0.0, high=float(MAX_DELAY), high_closed=True,
        whole=True,
    )  # fmt: skip


@struct.dataclass
class AdvisorMemory:
    """What a delayed advisor remembers, per environment."""

    past: jax.Array  # [E, MAX_DELAY, 2] its actions of the last steps, newest first
    started: jax.Array  # [E] bool: the episode has had a step (False after a reset)


def memory_init(n_envs: int) -> AdvisorMemory:
    return AdvisorMemory(
        past=jnp.zeros((n_envs, MAX_DELAY, spec.ACTION_SIZE), jnp.float32),
        started=jnp.zeros(n_envs, bool),
    )


def restart(memory: AdvisorMemory, done: jax.Array) -> AdvisorMemory:
    """Forgets the episodes that just ended (``done`` [E]): their next step starts afresh."""
    return memory.replace(started=memory.started & ~done)


def advisor_view(obs: jax.Array, quality: AdvisorQuality) -> jax.Array:
    """The observation [20] as the advisor sees it: its blind sector and range read no hit."""
    prox = obs[spec.OBS_PROXIMITY]
    blind = jnp.asarray(_DIRECTIONS) < 0.5 * quality.advisor_blind
    unseen = blind | (prox >= quality.advisor_range)
    seen = jnp.where(unseen, jnp.asarray(spec.MAX_RANGE, obs.dtype), prox)
    return obs.at[spec.OBS_PROXIMITY].set(seen)


Acting = Callable[[AdvisorQuality, AdvisorMemory, jax.Array, jax.Array], Any]


def make_acting(apply: Callable, params: Any) -> Acting:
    """``act(quality, memory, obs [E, 20], key) -> (a_adv [E, 2], memory)``: the advisor
    ``apply(params, obs)`` under the knobs (module docstring), for E environments."""
    low, high = jnp.asarray(_LOW), jnp.asarray(_HIGH)

    def one(quality, past, started, obs, key):
        now = jnp.clip(apply(params, advisor_view(obs, quality)), low, high).astype(jnp.float32)
        past = jnp.where(started, past, now[None])  # a new episode: nothing before its start
        history = jnp.concatenate([now[None], past])  # [MAX_DELAY + 1, 2], newest first
        delay = jnp.clip(jnp.round(quality.advisor_delay), 0, MAX_DELAY).astype(jnp.int32)
        action = history[delay]
        k_noise, k_random, k_pick = jax.random.split(key, 3)
        noisy = action + quality.advisor_noise * jax.random.normal(k_noise, action.shape)
        action = jnp.where(quality.advisor_noise > 0, noisy, action)
        uniform = jax.random.uniform(k_random, action.shape, minval=low, maxval=high)
        action = jnp.where(jax.random.uniform(k_pick) < quality.advisor_random, uniform, action)
        return jnp.clip(action, low, high), history[:MAX_DELAY]

    def act(quality: AdvisorQuality, memory: AdvisorMemory, obs: jax.Array, key: jax.Array):
        keys = jax.random.split(key, obs.shape[0])
        action, past = jax.vmap(one, in_axes=(None, 0, 0, 0, 0))(
            quality, memory.past, memory.started, obs, keys
        )
        return action, AdvisorMemory(past=past, started=jnp.ones_like(memory.started))

    return act


def changed_knobs(knobs: dict) -> list[str]:
    """``["advisor_random=0.3"]``: the knobs of ``knobs`` ({flat name: value}) that differ
    from their defaults, for labels."""
    defaults = {k: float(v) for k, v in flat_items(AdvisorQuality()).items()}
    return [f"{k}={float(v):g}" for k, v in knobs.items() if k in defaults and v != defaults[k]]


def advisor_key(key: jax.Array) -> jax.Array:
    """The advisor's key of a step whose key is ``key`` (``key`` itself stays as it was for
    everything else)."""
    return jax.random.fold_in(key, ADVISOR_STREAM)
