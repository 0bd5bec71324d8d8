"""The rule-based advisor of the paper (Appendix A, Algorithm A1, Table A1; §5.5).

Outline (per observation; no Python control flow on traced values)::

    p_min = min(P)
    if p_min > T_o:                                    # goal reaching, Eqs. (9), (10)
        ω = tanh(m1 δ);  V = 1 - exp(-m2 d)
    else:                                              # Braitenberg, Alg. A1 steps 14-24
        det_i = 1 - (max(p_i, d_dmax) - d_dmax) / (d_nd - d_dmax)  if p_i < d_nd  else 0
        V = V_max + ½ (b_R + b_L)·det
        ω = ½ m3 (b_R - b_L)·det                      # sign: see below
    V = clip(V, 0, 1);  ω = clip(ω, -1, 1)

Sign conventions, fixed by behaviour (docs/architecture.md, "Paper readings" R4): ω > 0
turns left (counter-clockwise), δ > 0 means the goal is on the left, and sensor 1 looks
left (``contract/spec.py``). Then goal-on-the-left ⇒ ω = tanh(m1 δ) > 0 ⇒ turn left, as
printed. The printed Braitenberg line ω = ½ m3 (b_L - b_R)·det comes from V-REP's
wheel-speed Braitenberg demo, where it is the *clockwise* rate v_L - v_R; with sensor 1 on
the left, an obstacle there must make the robot turn right, so in our counter-clockwise
convention the rate is ½ m3 (b_R - b_L)·det.
The tests pin both behaviours.

Table A1's arrays have 15 entries although n_sen = 16; the text says the rear sensors get
zero weight, so we pad with zeros to 16. The paper says both "p_min > T_o" (Alg. A1) and
"p_t < T_o" (§5.5) for the switch; at equality we use Braitenberg (the algorithm's ``else``).
"""

from __future__ import annotations

import jax.numpy as jnp
from flax import struct

from advisor_jax.contract import spec

_FRONT_LEFT = (-0.1, -0.2, -0.3, -0.4, -0.5, -0.6, -0.7, -0.8)


@struct.dataclass
class AdvisorParams:
    """Parameters of Algorithm A1 (Table A1). A pytree: can be vmapped or swept."""

    obstacle_threshold: float = 0.5  # T_o, m (0.5 simulation, 0.6 physical)
    no_detect_distance: float = 0.6  # d_nd, m
    max_detect_distance: float = 0.2  # d_dmax, m
    braitenberg_left: jnp.ndarray = struct.field(
        default_factory=lambda: jnp.array(_FRONT_LEFT + (0.0,) * 8, jnp.float32)
    )  # b_L
    braitenberg_right: jnp.ndarray = struct.field(
        default_factory=lambda: jnp.array(_FRONT_LEFT[::-1] + (0.0,) * 8, jnp.float32)
    )  # b_R
    v_max: float = 1.0  # V_max (normalised action units)
    m1: float = 1.0
    m2: float = 5.0
    m3: float = 1.0


def arena_advisor(env) -> AdvisorParams:
    """Table A1 advisor with the arena's obstacle threshold T_o (``env.obstacle_threshold``:
    0.5 m in simulation, 0.6 m in the physical arena)."""
    return AdvisorParams(obstacle_threshold=float(env.obstacle_threshold))


def advisor_action(obs: jnp.ndarray, params: AdvisorParams | None = None) -> jnp.ndarray:
    """Advisor action (V, ω) in normalised action units for one observation.

    Args:
      obs: [20] observation laid out as in ``advisor_jax/contract/spec.py``.
      params: advisor parameters; Table A1 simulation values by default.

    Returns:
      [2] action, V in [0, 1] and ω in [-1, 1].
    """
    p = params if params is not None else AdvisorParams()
    prox = obs[spec.OBS_PROXIMITY]
    delta = obs[spec.OBS_GOAL_ANGLE]
    dist = obs[spec.OBS_GOAL_DISTANCE]

    # Goal reaching, Eqs. (9) and (10).
    omega_goal = jnp.tanh(p.m1 * delta)
    v_goal = 1.0 - jnp.exp(-p.m2 * dist)

    # Braitenberg obstacle avoidance, Alg. A1 steps 14-22.
    clamped = jnp.maximum(prox, p.max_detect_distance)
    closeness = 1.0 - (clamped - p.max_detect_distance) / (
        p.no_detect_distance - p.max_detect_distance
    )
    det = jnp.where(prox < p.no_detect_distance, closeness, 0.0)
    v_avoid = p.v_max + 0.5 * jnp.dot(p.braitenberg_right + p.braitenberg_left, det)
    omega_avoid = 0.5 * p.m3 * jnp.dot(p.braitenberg_right - p.braitenberg_left, det)

    goal_mode = jnp.min(prox) > p.obstacle_threshold
    v = jnp.where(goal_mode, v_goal, v_avoid)
    omega = jnp.where(goal_mode, omega_goal, omega_avoid)
    return jnp.stack([jnp.clip(v, 0.0, 1.0), jnp.clip(omega, -1.0, 1.0)]).astype(obs.dtype)
