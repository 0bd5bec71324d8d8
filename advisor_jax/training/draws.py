"""A step's minibatches are drawn before the step's transition is stored.

Alg. 1 stores the step's transition (step 16) and then samples the update's minibatch. Here
both halves of a step read the state the step starts from: the collection acts with the
parameters before the step's update (as Alg. 1 does), the update draws from the buffer as
the step found it (``draw_batches``), with N (the AfP gate) as the step found it. The
step's transition is *pending*: stored at the start of the next step, before that step's
draw (``store_pending``), or at the end of the chunk.

The paper's own runs train asynchronously (§4.1), where a minibatch never waits for the
newest transition; we keep the update synchronous and one per step (R25). The two halves
are then independent, so a GPU runs the collection's kernels beside the update's
(``results/bench_draw_first/``; training unchanged over 16 seeds). The cost: a transition
joins the draws one step later, one of the ``warmup`` or more a batch is drawn from.

Why pending and not stored at the end of its own step: a store at the end writes the buffer
the step's draw read. XLA's fusion may duplicate the draw's gather into the update's kernels
and schedule it after the store, and the store then writes a copy of the whole buffer (twice
per step on a CPU: 0.82× there). Stored at the start of the next step, the write comes
before every read of that step in the single-step loop.
"""

from __future__ import annotations

from typing import Any, NamedTuple

import jax
import jax.numpy as jnp

from advisor_jax.agent.replay_buffer import ReplayState, Transition, replay_add, replay_init


class Draws(NamedTuple):
    """A step's minibatches and the keys of its updates."""

    batches: Any  # Transition, [updates_per_step, batch_size, ...]
    critic_keys: jax.Array  # [updates_per_step]: TD3's target smoothing noise
    key: jax.Array  # the state's key after the draw


def draw_batches(learner, updates_per_step: int, replay: ReplayState, key: jax.Array) -> Draws:
    """The step's ``updates_per_step`` minibatches (Alg. 2 step 6) from ``replay`` with
    ``learner.sample``, and TD3's smoothing keys, split from the state's ``key`` as each
    update always split them."""
    key, k_updates = jax.random.split(key)
    batches, critic_keys = [], []
    for _ in range(updates_per_step):
        k_updates, k_sample, k_critic = jax.random.split(k_updates, 3)
        batches.append(learner.sample(replay, k_sample))
        critic_keys.append(k_critic)
    stack = lambda *xs: jnp.stack(xs)  # noqa: E731
    return Draws(jax.tree.map(stack, *batches), stack(*critic_keys), key)


class Pending(NamedTuple):
    """A step's transition, to be stored at the start of the next step."""

    transition: Transition  # [E, ...]
    valid: jax.Array  # [E] bool: the rows to store (a baseline's offline phase stores none)


def nothing_pending(n_envs: int) -> Pending:
    """What a chunk's first step finds pending: nothing."""
    return Pending(replay_init(n_envs).data, jnp.zeros(n_envs, bool))


def store_pending(replay: ReplayState, pending: Pending) -> ReplayState:
    """``replay`` with the pending transition's valid rows added."""
    return replay_add(replay, pending.transition, pending.valid)
