"""The learner's update step as training runs it, in a loop to time or profile
(``bench_learner.py``, ``profile_learner.py``), and a replay buffer filled to sample from."""

from __future__ import annotations

import jax
import jax.numpy as jnp

from advisor_jax.agent.config import HParams
from advisor_jax.agent.learner import make_learner
from advisor_jax.agent.replay_buffer import Transition, replay_add, replay_init
from advisor_jax.contract import spec
from advisor_jax.training.compiler import compiler_options
from advisor_jax.training.program import PROGRAMS, holds_networks, program_layout

SMALL = dict(actor_hidden=(64, 64), critic_state_hidden=128, critic_hidden=(128, 128),
             buffer_size=4096, batch_size=128)  # fmt: skip


def require_whole_blocks(cfg, n_updates: int, program: str) -> str:
    """``program`` (one of ``program.PROGRAMS``) if its loop can run ``n_updates`` updates:
    any count for the general program, whole blocks of d for the steady and latency-bound
    ones; otherwise a ``ValueError`` naming the count, so that what a benchmark asks for is
    what it times (a general loop in their place would time other kernels)."""
    if program not in PROGRAMS:
        raise ValueError(f"program {program!r}: not one of {PROGRAMS}")
    if program != "general" and n_updates % cfg.delay:
        raise ValueError(
            f"{n_updates} updates: the {program} loop runs whole blocks of d = {cfg.delay} "
            f"updates (TD3's delay); give a multiple of {cfg.delay}, or the general program"
        )
    return program


def make_update_loop(
    cfg, n_updates: int, program: str = "general", agents_per_device: int | None = None
):
    """``n_updates`` calls of the learner's update, the exact step training runs, in a scan,
    with the layout and compiler options of training's ``program`` (``program.PROGRAMS``) for
    ``agents_per_device`` agents on one device (the held critics depend on it,
    ``program.holds_critics``; None: not known).

    * general: each update decides its delayed actor step by ``lax.cond``, XLA's scheduling.
    * steady: blocks of d updates written out in a row whose first takes the actor step, no
      conditional, each loop one graph (what one GPU gives bf16 populations its memory holds).
    * latency-bound: the steady loop with overlapping kernels (populations of at most
      ``program.latency_bound_agents``). Timed alone that way the update is not faster
      (``results/bench_train_steady/``): the program pays in the full step, where the
      collection's kernels overlap the update's, which only ``bench_train.py`` measures.

    The block programs need ``n_updates`` to be whole blocks of d (``require_whole_blocks``)."""
    hp = HParams()
    program, delay = require_whole_blocks(cfg, n_updates, program), cfg.delay
    steady = program != "general"
    layout = program_layout(program, cfg.precision, agents_per_device=agents_per_device)
    learner = make_learner(cfg, layout=layout)  # as training's

    def one_agent(learner_state, replay, key):
        def update(carry, u, update_fn=None):
            state, key = carry
            key, k_sample, k_critic = jax.random.split(key, 3)
            batch = learner.sample(replay, k_sample)
            if update_fn is None:  # the delay decided from the index by a cond
                state, _, _ = learner.update(state, batch, k_critic, hp, u)
            else:
                state, _, _ = update_fn(state, batch, k_critic, hp)
            return (state, key), None

        def block(carry, u):  # d updates from u, a multiple of d, written out as training's
            for j in range(delay):
                with_actor = learner.update_with_actor if j == 0 else learner.update_critic_only
                carry, _ = update(carry, u + j, with_actor)
            return carry, None

        body, starts = (
            (block, jnp.arange(0, n_updates, delay)) if steady else (update, jnp.arange(n_updates))
        )
        if holds_networks(program, cfg.precision):  # as training's program
            learner_state = learner.hold(learner_state)
        carry = (learner_state, key)
        (learner_state, _), _ = jax.lax.scan(body, carry, starts)
        return learner.release(learner_state)

    overlap = program == "latency-bound"
    options = compiler_options(cfg.precision, overlap=overlap, steady=steady)  # as training's
    return learner, jax.jit(jax.vmap(one_agent), donate_argnums=0, compiler_options=options)


def fill_replay(capacity: int, key) -> object:
    k1, k2, k3 = jax.random.split(key, 3)
    data = Transition(
        obs=jax.random.uniform(k1, (capacity, spec.OBS_SIZE)),
        action=jax.random.uniform(k2, (capacity, spec.ACTION_SIZE)),
        advisor_action=jax.random.uniform(k3, (capacity, spec.ACTION_SIZE)),
        reward=jnp.zeros(capacity),
        next_obs=jax.random.uniform(k1, (capacity, spec.OBS_SIZE)),
        terminal=jnp.zeros(capacity),
    )
    return replay_add(replay_init(capacity), data)
