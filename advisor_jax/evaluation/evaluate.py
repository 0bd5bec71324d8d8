"""Batched, deterministic policy evaluation (paper §6: success rate over test episodes).

``make_evaluate(env, policy_apply, episodes)`` returns ``evaluate_fn(params, key)``, which
runs ``episodes`` environments in parallel for h_max steps and keeps the outcome of the
FIRST episode of each (every first episode ends within h_max steps: goal, collision or
timeout). It is built on ``make_rollout``, the one rollout of this package (the export's
golden observations come from it too). Outline::

    states ← vmap(env.reset)(split(key, episodes))
    repeat h_max times:                                  # lax.scan, fixed length
        a ← vmap(policy_apply, (None, 0))(params, states.obs)   # no exploration noise
        states ← vmap(env.step)(states, a)
        record (done, outcome, length, return, collision speed)
    keep each environment's record at its first done step

``evaluate_fn`` is a pure function: jit it, or vmap it over a stack of ``params`` to
evaluate a whole sweep of agents in one program. The success rate is the paper's metric
(§6.1: "the ratio of the number of successful episodes to the total").
"""

from __future__ import annotations

from collections.abc import Callable, Mapping, Sequence
from typing import Any, NamedTuple

import jax
import jax.numpy as jnp
import numpy as np
from flax import struct

import envs
from advisor_jax.agent.advisor_quality import advisor_key, make_acting, memory_init, restart
from advisor_jax.agent.networks import make_actor
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


def collision_speed_sd(m: EvalMetrics, empty: float = 0.0) -> jax.Array:
    """Standard deviation (m/s, over collision episodes, ddof 0) of the collision speed;
    ``empty`` when there are none. With ``mean_collision_speed`` and the collision count
    it lets seeds be pooled into the spread over all their collisions (Table 3)."""
    hit = m.outcome == COLLISION
    count = jnp.maximum(jnp.sum(hit, axis=-1), 1)
    mean = mean_collision_speed(m)
    centred = jnp.where(hit, m.collision_speed - mean[..., None], 0.0)
    sd = jnp.sqrt(jnp.sum(centred**2, axis=-1) / count)
    return jnp.where(jnp.any(hit, axis=-1), sd, empty)


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
        "collision_speed_sd": r(collision_speed_sd(m)) if collisions else None,
        "mean_length": r(jnp.mean(m.length)),
        "mean_return": r(jnp.mean(m.episode_return)),
    }


class StatefulPolicy(NamedTuple):
    """A policy with memory and random draws of its own (an advisor under its quality knobs,
    ``agent/advisor_quality.py``); a plain ``PolicyApply`` has neither."""

    init: Callable[[int], Any]  # n_envs -> memory
    act: Callable[..., tuple[jax.Array, Any]]  # (params, memory, obs [E, 20], key) -> (a, memory)
    restart: Callable[[Any, jax.Array], Any]  # (memory, done [E]) -> memory


def _stateful(policy: PolicyApply | StatefulPolicy) -> StatefulPolicy:
    if isinstance(policy, StatefulPolicy):
        return policy
    act = jax.vmap(policy, in_axes=(None, 0))
    return StatefulPolicy(lambda n: (), lambda p, m, obs, key: (act(p, obs), m), lambda m, d: m)


def advisor_policy(advisor) -> StatefulPolicy:
    """An advisor (``agent/advisors.Advisor``) as a policy whose params are its quality knobs
    (``AdvisorQuality``): the advisor the trainer consults, evaluated alone."""
    act = make_acting(advisor.apply, advisor.params)
    return StatefulPolicy(memory_init, act, restart)


def make_rollout(
    env: NavEnv, policy: PolicyApply | StatefulPolicy, n_envs: int, steps: int, record: Callable
) -> Callable[[Any, jax.Array], tuple[Any, Any]]:
    """The one rollout: ``rollout_fn(params, key) -> (final states, records [steps, ...])``.

    ``n_envs`` environments reset from ``split(key, n_envs)`` and step ``steps`` times with
    the policy (no exploration noise; auto-reset on). Each step stores
    ``record(state_before, state_after)``. A ``StatefulPolicy`` draws from
    ``advisor_key(key)`` folded with the step index, so the episodes are those of any policy
    given ``key``. Pure: jit or vmap it at the call site.
    """
    policy = _stateful(policy)
    step = jax.vmap(env.step)

    def rollout_fn(params: Any, key: jax.Array):
        act_key = advisor_key(key)

        def body(carry, t):
            state, memory = carry
            action, memory = policy.act(params, memory, state.obs, jax.random.fold_in(act_key, t))
            new = step(state, action)
            return (new, policy.restart(memory, new.done)), record(state, new)

        states = jax.vmap(env.reset)(jax.random.split(key, n_envs))
        carry = (states, policy.init(n_envs))
        (states, _), records = jax.lax.scan(body, carry, jnp.arange(steps, dtype=jnp.int32))
        return states, records

    return rollout_fn


def _episode_end(_, s) -> EvalMetrics:
    """What a step records for evaluation: the ended episode's results, and whether it ended."""
    metrics = EvalMetrics(
        outcome=s.outcome,
        length=s.episode_length,
        episode_return=s.episode_return,
        collision_speed=s.collision_speed,
    )
    return metrics, s.done


def make_evaluate(
    env: NavEnv, policy_apply: PolicyApply | StatefulPolicy, episodes: int
) -> Callable[[Any, jax.Array], EvalMetrics]:
    """Builds ``evaluate_fn(policy_params, key) -> EvalMetrics`` (jittable, vmappable).

    Every environment's first episode ends within h_max steps (goal, collision or
    timeout); its results are those of the first step that reports ``done``.
    """
    if int(episodes) <= 0:
        raise ValueError(f"episodes must be a positive integer, got {episodes}")
    rollout_fn = make_rollout(env, policy_apply, int(episodes), env.max_episode_steps, _episode_end)

    def evaluate_fn(policy_params: Any, key: jax.Array) -> EvalMetrics:
        _, (per_step, done) = rollout_fn(policy_params, key)  # [h_max, episodes]
        first = jnp.argmax(done, axis=0)  # index of the first episode's last step
        return jax.tree.map(lambda x: jnp.take_along_axis(x, first[None], 0)[0], per_step)

    return evaluate_fn


def rollout_observations(env, policy_apply, params, key, n_envs: int, steps: int) -> np.ndarray:
    """[n_envs · steps, 20] observations met by the deterministic policy (auto-reset on)."""
    rollout_fn = make_rollout(env, policy_apply, n_envs, steps, lambda before, _: before.obs)
    _, obs = jax.jit(rollout_fn)(params, key)
    return np.asarray(obs).reshape(-1, obs.shape[-1])


# Populations ----------------------------------------------------------------------------
#
# Every agent of a population is evaluated on the *same* episodes (same key, so the same
# starts and goals): differences between agents are then paired, not sampling noise.


def population_evaluator(
    arena: str,
    episodes: int,
    actor_hidden: Sequence[int],
    max_episode_steps: int = 0,
    motion: str = "kinematic",
) -> Callable[[Any, jax.Array], EvalMetrics]:
    """jit(vmap over agents) of the evaluation of ``make_actor(actor_hidden)`` in ``arena``
    under the ``motion`` model the agents trained with:
    ``(stacked actor params, key) -> EvalMetrics [agents, episodes]``."""
    return policy_population_evaluator(
        arena, episodes, make_actor(actor_hidden).apply, max_episode_steps, motion
    )


def policy_population_evaluator(
    arena: str,
    episodes: int,
    policy_apply: PolicyApply,
    max_episode_steps: int = 0,
    motion: str = "kinematic",
) -> Callable[[Any, jax.Array], EvalMetrics]:
    """``population_evaluator`` of any policy: ``policy_apply(params, obs) -> action`` (a
    brax agent's, ``agent.brax_agents.policy_apply``) over params stacked on agents."""
    env = envs.make_env(arena, motion=motion, max_episode_steps=max_episode_steps)  # 0: h_max
    fn = make_evaluate(env, policy_apply, episodes)
    return jax.jit(jax.vmap(fn, in_axes=(0, None)))


def advisor_evaluator(
    env: NavEnv, advisor, episodes: int
) -> Callable[[Any, jax.Array], EvalMetrics]:
    """jit(vmap over quality knobs) of the evaluation of ``advisor`` (an ``Advisor`` resolved
    for ``env``'s arena) alone: ``(stacked AdvisorQuality, key) -> EvalMetrics [n, episodes]``,
    on the episodes any policy gets from ``key``."""
    fn = make_evaluate(env, advisor_policy(advisor), episodes)
    return jax.jit(jax.vmap(fn, in_axes=(0, None)))


def success_table(scores: Mapping[str, Any], agents: Sequence[int] | None = None):
    """[agents, episodes] float array of one arena's ``evaluate_population`` output (or
    eval.json's): 1.0 where the agent reached the goal, NaN rows for agents without outcomes
    (diverged); None where the record holds no ``outcomes`` (runs before 2026-12-08)."""
    outcomes = scores.get("outcomes")
    if outcomes is None:
        return None
    agents = range(len(outcomes)) if agents is None else agents
    rows = [
        np.full(scores["episodes"], np.nan)
        if outcomes[i] is None
        else (np.frombuffer(outcomes[i].encode(), np.uint8) - ord("0") == GOAL).astype(float)
        for i in agents
    ]
    return np.array(rows).reshape(len(rows), scores["episodes"])


def evaluate_population(
    evaluators: Mapping[str, Callable], actor_params, key: jax.Array, diverged=None
) -> dict[str, dict[str, list]]:
    """Success / collision / timeout rates and mean collision speed per agent and arena.

    Args:
      evaluators: ``{arena: population_evaluator(arena, ...)}``.
      actor_params: actor params stacked on a leading agent axis.
      key: PRNG key of the episodes (shared by all agents).
      diverged: [agents] bool; those agents get None rates.

    Returns:
      ``{arena: {"success": [...], "collision": [...], "timeout": [...],
      "collision_speed": [...], "collision_speed_sd": [...], "outcomes": [...],
      "episodes": n}}`` with one entry per agent (the speeds' mean and spread over its
      collision episodes, None without any; ``outcomes``: each episode's outcome code as a
      digit, 1 goal, 2 collision, 3 timeout: what ``stats.seeds_and_episodes_interval``
      needs).
    """
    out = {}
    for arena, evaluator in evaluators.items():
        metrics = evaluator(actor_params, key)
        rates = {
            "success": success_rate(metrics),
            "collision": collision_rate(metrics),
            "timeout": timeout_rate(metrics),
            "collision_speed": mean_collision_speed(metrics, empty=float("nan")),
            "collision_speed_sd": collision_speed_sd(metrics, empty=float("nan")),
        }
        result = {}
        for name, value in rates.items():
            value = np.asarray(value, np.float64)
            if diverged is not None:
                value = np.where(diverged, np.nan, value)
            result[name] = [None if np.isnan(v) else float(v) for v in value]
        result["outcomes"] = [
            None if diverged is not None and diverged[i] else "".join(map(str, row))
            for i, row in enumerate(np.asarray(metrics.outcome))
        ]
        result["episodes"] = int(metrics.outcome.shape[-1])
        out[arena] = result
    return out
