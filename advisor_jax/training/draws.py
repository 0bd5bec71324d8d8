"""A step's minibatches are drawn before the step stores its transition.

Alg. 1 stores the step's transition (step 16) and then samples the update's minibatch. Here
both halves of a step read the state the step starts from: the collection acts with the
parameters before the step's update (as Alg. 1 does), the update draws from the buffer as
the step found it (``draw_minibatches``), with N (the AfP gate) as the step found it, and
the step's transition is stored after the draw (``store_after``).

The paper's own runs train asynchronously (§4.1), where a minibatch never waits for the
newest transition; we keep the update synchronous and one per step (R25). The two halves
are then independent, so a GPU runs the collection's kernels beside the update's (1 agent
1.11×, 4 agents 1.07×, 16 and 64 agents 0.99×; training unchanged over 16 seeds:
``results/bench_draw_first/``). The cost: a transition joins the draws one step later, one
of the ``warmup`` or more transitions a batch is drawn from.
"""

from __future__ import annotations

from typing import Any, NamedTuple

import jax
import jax.numpy as jnp

from advisor_jax.agent.replay_buffer import ReplayState, Transition, replay_add


class Draws(NamedTuple):
    """A step's minibatches and the keys of its updates."""

    batches: Any  # Transition, [updates_per_step, batch_size, ...]
    critic_keys: jax.Array  # [updates_per_step]: TD3's target smoothing noise
    key: jax.Array  # the state's key after the draw


def draw_minibatches(learner, updates_per_step: int, replay: ReplayState, key: jax.Array) -> Draws:
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


def store_after(after: Any, replay: ReplayState, transition: Transition, valid=None) -> ReplayState:
    """``replay`` with ``transition`` added (``replay_add``'s ``valid``), written once
    ``after`` (what was read from the buffer: the draws' batches) is computed, so that the
    write cannot precede a read of the buffer it overwrites."""
    _, replay = jax.lax.optimization_barrier((after, replay))
    return replay_add(replay, transition, valid)
