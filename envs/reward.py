"""Eq. (8) from two observations: the reward a planner can compute from predicted states.

The env (``navigation.NavEnv._step``) computes Eq. (8) from the pose, the goal and the
sensors; a model-based controller (``agent/mpc.py``, the MCP + model-free baseline of
docs/baselines.md) only has predicted observations ŝ. ``eq8_from_obs`` is the env's reward
rewritten on the observation alone, with the same operations in the same order, so on
real transitions it returns the env's reward bit for bit wherever the observation
determines it (tested: ``tests/agent/test_dynamics_mpc.py``)::

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


def return_bounds(cfg: EnvConfig, gamma: jax.Array | float) -> tuple[jax.Array, jax.Array]:
    """The smallest interval [lo, hi] that holds every discounted return of Eq. (8).

    For any state and any policy, G = Σ_t γ^t r_t (t from 0, terminal steps end the sum, a
    timeout bootstraps and so continues it) lies in [lo, hi]::

        hi =  c1 + k1 v_max dt / (1 - γ) + k2 R        lo = -(c2 + k1 v_max dt / (1 - γ) + k2 R)

    * **Terminal reward**: at most one, c1 (goal) or -c2 (collision), weighted by γ^T ≤ 1.
    * **Distance shaping** k1 (d_{t-1} - d_t): each step moves the robot at most v_max dt
      (``kinematic``: v ≤ v_max; ``mjx``: the body never outruns the commanded V ≤ v_max,
      ``motion.py``, tested), so the goal distance changes by at most that:
      |Σ| ≤ k1 v_max dt/(1-γ).
    * **Proximity shaping** k2 (p_t - p_{t-1}) with p ∈ [0, R] (R = max_range): the discounted
      sum telescopes, Σ_{t<T} γ^t (p_{t+1} - p_t) = -p_0 + Σ_{0<t<T} (γ^{t-1} - γ^t) p_t
      + γ^{T-1} p_T, whose positive weights sum to 1, so it lies in [-R, R]: |Σ| ≤ k2 R.

    With the paper's settings (c1 = c2 = 10, k1 = k2 = 5, v_max dt = 0.05 m, R = 1 m, γ = 0.9)
    this is [-17.5, 17.5]. A critic whose mean Q leaves it is overestimating; the learner's
    ``clip_q_target`` switch clips its TD targets Q̂ into it (docs/architecture.md, R35).
    ``gamma`` may be traced (a vmapped hyperparameter); γ < 1.
    """
    shaping = cfg.k_distance * cfg.v_max * cfg.dt / (1.0 - gamma) + cfg.k_proximity * cfg.max_range
    return -(cfg.collision_penalty + shaping), cfg.goal_reward + shaping
