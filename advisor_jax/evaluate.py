"""Batched, deterministic policy evaluation (paper §6: success rate over test episodes).

``make_evaluate(env, policy_apply, episodes)`` returns ``evaluate_fn(params, key)``, which
runs ``episodes`` environments in parallel for h_max steps and keeps the outcome of the
FIRST episode of each (every first episode ends within h_max steps: goal, collision or
timeout). Outline::

    states ← vmap(env.reset)(split(key, episodes))
    repeat h_max times:                                  # lax.scan, fixed length
        a ← vmap(policy_apply, (None, 0))(params, states.obs)   # no exploration noise
        states ← vmap(env.step)(states, a)
        record (outcome, length, return, collision speed) where done and not yet recorded

``evaluate_fn`` is a pure function: jit it, or vmap it over a stack of ``params`` to
evaluate a whole sweep of agents in one program. The success rate is the paper's metric
(§6.1: "the ratio of the number of successful episodes to the total").
"""

from __future__ import annotations

from collections.abc import Callable
from typing import Any

import jax
import jax.numpy as jnp
from flax import struct

from envs.navigation import COLLISION, GOAL, TIMEOUT, NavEnv

PolicyApply = Callable[[Any, jax.Array], jax.Array]  # (params, obs [20]) -> action [2]


@struct.dataclass
class EvalMetrics:
    """Per-episode results of one evaluation (leading axes: [agents...,] episodes)."""

    outcome: jax.Array  # [E] int32: 1 goal, 2 collision, 3 timeout (envs.navigation codes)
    length: jax.Array  # [E] int32 steps
    episode_return: jax.Array  # [E] f32
    collision_speed: jax.Array  # [E] f32 m/s, mean |V| of the last 3 steps (collisions only)

    @property
    def success_rate(self) -> jax.Array:
        return success_rate(self)

    @property
    def collision_rate(self) -> jax.Array:
        return collision_rate(self)

    @property
    def timeout_rate(self) -> jax.Array:
        return timeout_rate(self)

    @property
    def mean_collision_speed(self) -> jax.Array:
        return mean_collision_speed(self)


def _rate(m: EvalMetrics, code: int) -> jax.Array:
    return jnp.mean((m.outcome == code).astype(jnp.float32), axis=-1)


def success_rate(m: EvalMetrics) -> jax.Array:
    """Fraction of episodes that reached the goal (per agent if stacked)."""
    return _rate(m, GOAL)


def collision_rate(m: EvalMetrics) -> jax.Array:
    return _rate(m, COLLISION)


def timeout_rate(m: EvalMetrics) -> jax.Array:
    return _rate(m, TIMEOUT)


def mean_collision_speed(m: EvalMetrics, empty: float = 0.0) -> jax.Array:
    """Mean collision speed (m/s) over collision episodes; ``empty`` when there are none.

    The division is guarded, so no NaN arises when there are no collisions (the value is
    then ``empty``: 0 by default, so sweeps can average it; ``summary`` reports None).
    """
    hit = m.outcome == COLLISION
    count = jnp.sum(hit, axis=-1)
    total = jnp.sum(jnp.where(hit, m.collision_speed, 0.0), axis=-1)
    return jnp.where(count > 0, total / jnp.maximum(count, 1), empty)


def summary(m: EvalMetrics) -> dict[str, float]:
    """Host-side summary of an unstacked evaluation (plain floats, JSON-able)."""
    collisions = int(jnp.sum(m.outcome == COLLISION))
    r = lambda x: round(float(x), 6)  # noqa: E731  (float32 → tidy decimal)
    return {
        "episodes": int(m.outcome.shape[-1]),
        "success_rate": r(success_rate(m)),
        "collision_rate": r(collision_rate(m)),
        "timeout_rate": r(timeout_rate(m)),
        "mean_collision_speed": r(mean_collision_speed(m)) if collisions else None,
        "mean_length": r(jnp.mean(m.length)),
        "mean_return": r(jnp.mean(m.episode_return)),
    }


@struct.dataclass
class _Carry:
    state: Any  # NavState [E]
    metrics: EvalMetrics
    recorded: jax.Array  # [E] bool


def make_evaluate(
    env: NavEnv, policy_apply: PolicyApply, episodes: int
) -> Callable[[Any, jax.Array], EvalMetrics]:
    """Builds ``evaluate_fn(policy_params, key) -> EvalMetrics`` (jittable, vmappable)."""
    if int(episodes) <= 0:
        raise ValueError(f"episodes must be a positive integer, got {episodes}")
    episodes = int(episodes)
    horizon = env.max_episode_steps
    act = jax.vmap(policy_apply, in_axes=(None, 0))
    step = jax.vmap(env.step)

    def evaluate_fn(policy_params: Any, key: jax.Array) -> EvalMetrics:
        state = jax.vmap(env.reset)(jax.random.split(key, episodes))
        zeros_i = jnp.zeros(episodes, jnp.int32)
        zeros_f = jnp.zeros(episodes, jnp.float32)
        metrics = EvalMetrics(
            outcome=zeros_i, length=zeros_i, episode_return=zeros_f, collision_speed=zeros_f
        )
        carry = _Carry(state=state, metrics=metrics, recorded=jnp.zeros(episodes, bool))

        def body(c: _Carry, _) -> tuple[_Carry, None]:
            s = step(c.state, act(policy_params, c.state.obs))
            new = s.done & ~c.recorded
            pick = lambda fresh, old: jnp.where(new, fresh, old)  # noqa: E731
            m = EvalMetrics(
                outcome=pick(s.outcome, c.metrics.outcome),
                length=pick(s.episode_length, c.metrics.length),
                episode_return=pick(s.episode_return, c.metrics.episode_return),
                collision_speed=pick(s.collision_speed, c.metrics.collision_speed),
            )
            return _Carry(state=s, metrics=m, recorded=c.recorded | s.done), None

        carry, _ = jax.lax.scan(body, carry, None, length=horizon)
        return carry.metrics

    return evaluate_fn
