"""A step's minibatches are drawn before the step's transition is stored.

Alg. 1 stores the step's transition (step 16) and then samples the update's minibatch. Here
both halves of a step read the state the step starts from: the collection acts with the
parameters before the step's update (as Alg. 1 does), the update draws from the buffer as
the step found it (``draw_batches``), with N (the AfP gate) as the step found it. The
step's transition is stored after the draw, where depends on the loop (below).

The paper's own runs train asynchronously (§4.1), where a minibatch never waits for the
newest transition; we keep the update synchronous and one per step (R25). The two halves
are then independent, so a GPU runs the collection's kernels beside the update's
(``results/bench_draw_first/``; training unchanged over 16 seeds). The cost: a transition
joins the draws one step later, one of the ``warmup`` or more a batch is drawn from.

Where the store goes. A store free to go anywhere after the draw writes the buffer the draw
reads: XLA's fusion may duplicate the draw's gather into the update's kernels and schedule a
duplicate after the store, which then writes a copy of the whole buffer (twice per step on a
CPU: 0.82×). So:

* the single-step loop (the general program, every CPU's) keeps the transition *pending*
  and stores it at the start of the next step (``store_pending``), or at the end of the
  chunk (``scan_pending``): the write comes before every read of the loop's body;
* the blocks of d steps of the steady and latency-bound programs (which only GPUs pick)
  store it once the step's update is computed (``store_after``, an optimization barrier):
  pending, a block's next step would write the buffer its previous step's draw read, and on
  a GPU that held a copy of it (0.97× at 16 and 64 agents). A barrier copies the buffer on a
  CPU, not on a GPU;
* the latency-bound blocks of one agent store it with no barrier (``store_free``): the next
  step's draw need not wait for this step's update (1.05× on an H100; 2 agents ran 0.87×,
  ``program.stores_free``).

The three put the same transition in the same slot before the same draw: the same training.
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


def scan_pending(step, state, steps: jax.Array, n_envs: int):
    """``lax.scan`` of ``step(state, step index, pending) -> (state, metrics, pending)`` over
    ``steps``: each step stores the transition the one before left pending (the first finds
    none), and the last one's is stored at the end. (state, metrics)."""

    def pending_step(carry, index):
        state, metrics, pending = step(carry[0], index, carry[1])
        return (state, pending), metrics

    (state, last), metrics = jax.lax.scan(pending_step, (state, nothing_pending(n_envs)), steps)
    return state.replace(replay=store_pending(state.replay, last)), metrics


def store_after(replay: ReplayState, transition: Transition, fed):
    """``(fed, replay)`` with ``transition`` added to ``replay`` once ``fed`` is computed:
    everything the step's draw fed into (the update's learner state, metrics and flags)."""
    fed, replay = jax.lax.optimization_barrier((fed, replay))
    return fed, replay_add(replay, transition)


def store_free(replay: ReplayState, transition: Transition, fed):
    """``(fed, replay)`` with ``transition`` added to ``replay``, free to be scheduled as soon
    as the step's draw has read the buffer: the latency-bound blocks of one agent
    (``program.stores_free``)."""
    return fed, replay_add(replay, transition)
