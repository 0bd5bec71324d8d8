"""Evaluation of trained populations: the deterministic actor (no noise, no advisor).

Every agent of a population is evaluated on the *same* episodes (same key, so the same
starts and goals): differences between agents are then paired, not sampling noise.
"""

from __future__ import annotations

import functools
from collections.abc import Sequence

import jax
import numpy as np

import envs
from advisor_jax import evaluate
from advisor_jax.networks import Actor


@functools.lru_cache(maxsize=16)
def population_evaluator(arena: str, max_episode_steps: int, episodes: int, hidden: tuple):
    """jit(vmap over agents) of the evaluation of ``Actor(hidden)`` in ``arena``; cached."""
    overrides = {"max_episode_steps": max_episode_steps} if max_episode_steps else {}
    env = envs.make_env(arena, **overrides)
    fn = evaluate.make_evaluate(env, Actor(hidden=hidden).apply, episodes)
    return jax.jit(jax.vmap(fn, in_axes=(0, None)))


def evaluate_population(
    actor_params,
    actor_hidden: Sequence[int],
    *,
    arenas: Sequence[str],
    episodes: int,
    key: jax.Array,
    max_episode_steps: int = 0,
    diverged: np.ndarray | None = None,
) -> dict[str, dict[str, list]]:
    """Success / collision / timeout rates and mean collision speed per agent and arena.

    Args:
      actor_params: actor params stacked on a leading agent axis.
      actor_hidden: hidden widths of the actor (``AgentConfig.actor_hidden``).
      arenas: arena names, e.g. ("training", "validation").
      episodes: evaluation episodes per agent and arena (the paper uses 100).
      key: PRNG key of the episodes (shared by all agents).
      max_episode_steps: h_max override (0 = the arena's default).
      diverged: [agents] bool; those agents get NaN rates.

    Returns:
      ``{arena: {"success": [...], "collision": [...], "timeout": [...],
      "collision_speed": [...], "episodes": n}}`` with one entry per agent.
    """
    out = {}
    hidden = tuple(int(w) for w in actor_hidden)
    for arena in arenas:
        evaluator = population_evaluator(arena, int(max_episode_steps), int(episodes), hidden)
        metrics = evaluator(actor_params, key)
        rates = {
            "success": evaluate.success_rate(metrics),
            "collision": evaluate.collision_rate(metrics),
            "timeout": evaluate.timeout_rate(metrics),
            "collision_speed": evaluate.mean_collision_speed(metrics, empty=float("nan")),
        }
        result = {}
        for name, value in rates.items():
            value = np.asarray(value, np.float64)
            if diverged is not None:
                value = np.where(diverged, np.nan, value)
            result[name] = [None if np.isnan(v) else float(v) for v in value]
        result["episodes"] = int(episodes)
        out[arena] = result
    return out
