"""Eq. (8) from two observations: the reward a planner can compute from predicted states.

The env (``navigation.NavEnv._step``) computes Eq. (8) from the pose, the goal and the
sensors; a model-based controller (``agent/mpc.py``, the MCP + model-free baseline of
docs/baselines.md) only has predicted observations ŝ. ``eq8_from_obs`` is the env's reward
rewritten on the observation alone, with the same operations in the same order, so on
real transitions it returns the env's reward bit for bit wherever the observation
determines it (tested: ``tests/learn/test_dynamics_mpc.py``)::

    P̂ = clip(P, 0, max_range);  d̂ = max(d, 0);  p = min P̂      (predictions may leave
                                                                the contract's ranges)
    goal      = d̂_t ≤ T_g
    collision = p_t ≤ T_c  and not goal                        (the goal wins a tie)
    r         = c1 if goal, −c2 if collision, else k1 (d̂_{t−1} − d̂_t) + k2 (p_t − p_{t−1})

Differences from the env, all because the observation does not carry the information:

* **Footprint collision** (``EnvConfig.footprint_collision``, R10): the env also ends an
  episode when the round footprint touches a box between two sensor rays. That needs the
  pose and the boxes, so it is invisible here: on such a step the env gives −c2 and this
  function the shaping term.
* **Timeout**: not needed; a timeout step gets the shaping term in both (no step count in s).
* δ, v_x, v_y enter no reward, so their prediction errors (and the heading ambiguity of v at
  rest) do not matter here.

Pure and elementwise over leading axes: jit / vmap freely (e.g. over candidates and steps).
"""

from __future__ import annotations

import jax
import jax.numpy as jnp

from advisor_jax.contract import spec
from envs.state import EnvConfig


def eq8_from_obs(
    prev_obs: jax.Array, obs: jax.Array, cfg: EnvConfig
) -> tuple[jax.Array, jax.Array, jax.Array]:
    """Eq. (8) of the step ``prev_obs → obs`` (both [..., 20]) with the settings of ``cfg``.

    Returns ``(reward, goal, collision)``, each [...]: float32 reward, and the two terminal
    events as seen by the observation (goal wins a tie; no footprint test, see module doc).
    """
    dist_prev = jnp.maximum(prev_obs[..., spec.OBS_GOAL_DISTANCE], 0.0)
    dist = jnp.maximum(obs[..., spec.OBS_GOAL_DISTANCE], 0.0)
    p_prev = jnp.min(jnp.clip(prev_obs[..., spec.OBS_PROXIMITY], 0.0, cfg.max_range), axis=-1)
    p_min = jnp.min(jnp.clip(obs[..., spec.OBS_PROXIMITY], 0.0, cfg.max_range), axis=-1)
    goal = dist <= cfg.goal_tolerance
    collision = (p_min <= cfg.collision_distance) & ~goal
    shaped = cfg.k_distance * (dist_prev - dist) + cfg.k_proximity * (p_min - p_prev)
    reward = jnp.where(goal, cfg.goal_reward, jnp.where(collision, -cfg.collision_penalty, shaped))
    return reward.astype(jnp.float32), goal, collision
