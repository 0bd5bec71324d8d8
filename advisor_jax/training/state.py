"""What one agent carries through the training scan (``TrainState``), and the pure updates
of its episode log and actor snapshots that the core's step applies (``training/train.py``).
"""

from __future__ import annotations

from typing import Any

import jax
import jax.numpy as jnp
from flax import struct

import envs
from advisor_jax.agent.advisor_quality import AdvisorMemory
from advisor_jax.agent.learner import LearnerState
from advisor_jax.agent.noise import OUState
from advisor_jax.agent.replay_buffer import ReplayState


@struct.dataclass
class EpisodeLog:
    """Per-episode metrics of one agent, written at the index of each finished episode."""

    outcome: jax.Array  # [N_total] int32: 0 = not played (yet), else envs.GOAL, COLLISION, TIMEOUT
    length: jax.Array  # [N_total] int32 steps
    episode_return: jax.Array  # [N_total] f32
    collision_speed: jax.Array  # [N_total] f32 m/s, NaN unless the episode was a collision
    actor_steps: jax.Array  # [N_total] int32 steps that executed the actor's action


@struct.dataclass
class ActorSnapshots:
    """One agent's actor as it was on completing each of ``TrainConfig.snapshot_episodes``
    (leading axis [K]; K = 0 without any): taken at the end of the step whose episode reached
    the count, after that step's update, which is where a run of that many episodes stops."""

    actor: Any  # actor params, leading axis [K]
    taken: jax.Array  # [K] bool: the agent has completed that many episodes
    diverged: jax.Array  # [K] bool: its losses had gone non-finite by then (not evaluated)


@struct.dataclass
class TrainState:
    """Everything one agent carries through the scan; the same structure for every config."""

    learner: LearnerState
    replay: ReplayState
    env: Any  # envs NavState, leading axis [E]
    noise: OUState  # [E, 2]
    advisor: AdvisorMemory  # [E, ...] what a delayed advisor remembers (advisor_quality)
    actor_steps: jax.Array  # [E] int32, actor-fired steps of the running episodes
    episodes: jax.Array  # () int32, completed episodes N (Eq. 1)
    env_steps: jax.Array  # () int32, environment steps taken while active (all envs)
    diverged: jax.Array  # () bool, a loss went non-finite: the agent is frozen
    log: EpisodeLog
    snapshots: ActorSnapshots
    key: jax.Array


def empty_log(n_total: int) -> EpisodeLog:
    """The log of an agent that has played none of its ``n_total`` episodes."""
    return EpisodeLog(
        outcome=jnp.zeros(n_total, jnp.int32),
        length=jnp.zeros(n_total, jnp.int32),
        episode_return=jnp.zeros(n_total, jnp.float32),
        collision_speed=jnp.full(n_total, jnp.nan, jnp.float32),
        actor_steps=jnp.zeros(n_total, jnp.int32),
    )


def no_snapshots(actor, snapshot_at: jax.Array) -> ActorSnapshots:
    k = snapshot_at.shape[0]
    return ActorSnapshots(
        actor=jax.tree.map(lambda p: jnp.zeros((k, *p.shape), p.dtype), actor),
        taken=jnp.zeros(k, bool),
        diverged=jnp.zeros(k, bool),
    )


def take_snapshots(state: TrainState, snapshot_at: jax.Array) -> ActorSnapshots:
    """Copies the actor into every snapshot whose episode count was just reached."""
    snaps = state.snapshots
    now = (state.episodes >= snapshot_at) & ~snaps.taken  # [K]

    def keep(stored, current):
        return jnp.where(now.reshape(-1, *([1] * current.ndim)), current[None], stored)

    return ActorSnapshots(
        actor=jax.tree.map(keep, snaps.actor, state.learner.actor),
        taken=snaps.taken | now,
        diverged=jnp.where(now, state.diverged, snaps.diverged),
    )


def write_episodes(log: EpisodeLog, episodes, env_state, actor_steps, done) -> EpisodeLog:
    """Stores the metrics of every env whose episode just ended (``done`` [E]) at its
    episode index."""
    n_total = log.outcome.shape[0]
    slot = episodes + jnp.cumsum(done.astype(jnp.int32)) - 1
    slot = jnp.where(done, slot, n_total)  # out of range: dropped
    speed = jnp.where(env_state.outcome == envs.COLLISION, env_state.collision_speed, jnp.nan)
    return EpisodeLog(
        outcome=log.outcome.at[slot].set(env_state.outcome, mode="drop"),
        length=log.length.at[slot].set(env_state.episode_length, mode="drop"),
        episode_return=log.episode_return.at[slot].set(env_state.episode_return, mode="drop"),
        collision_speed=log.collision_speed.at[slot].set(speed, mode="drop"),
        actor_steps=log.actor_steps.at[slot].set(actor_steps, mode="drop"),
    )
