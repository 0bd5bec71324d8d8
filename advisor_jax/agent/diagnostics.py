"""What an actor update did, for the per-agent training log (issue: seeds that collapse).

Pure functions of one batch's arrays; ``learner.actor_step`` adds their values to its
metrics under ``diag/``. NaN means "not defined for this agent type or batch": the host loop
averages finite values only, and divergence is decided on losses, Q and gradient norms.
"""

from __future__ import annotations

import jax
import jax.numpy as jnp

Metrics = dict[str, jax.Array]


def actor_diagnostics(
    actions: jax.Array, advisor_actions: jax.Array, grad_q: jax.Array, targets, afp: bool
) -> Metrics:
    """What an actor update did, per batch (all under ``diag/``; NaN where not defined).

    * ``diag/grad_q_rms``: rms_i ‖∇_aQ_1(s_i, π(s_i))‖ (every algorithm).
    * ``diag/step``: mean ‖step_i‖ of Eq. (2) (β∇_aQ or its scale-free form; ADDPG family).
    * ``diag/advisor_gap``: mean ‖a_adv,i − π(s_i)‖ over the samples AfP replaced.
    * ``diag/q_gain``: mean Q(s_i, a_adv,i) − Q(s_i, â_i), before replacement (AfP).
    * ``diag/saturated``: fraction of output heads at their bounds (sigmoid V within 0.01 of
      0 or 1, tanh ω within 0.01 of ±1): a saturated head passes almost no gradient.
    """
    norm = lambda x: jnp.sqrt(jnp.sum(jnp.square(x), axis=-1))  # noqa: E731
    nan = jnp.full((), jnp.nan, actions.dtype)
    v, w = actions[..., 0], actions[..., 1]
    saturated = jnp.stack([(v < 0.01) | (v > 0.99), jnp.abs(w) > 0.99], axis=-1)
    out = {
        "diag/grad_q_rms": jnp.sqrt(jnp.mean(jnp.square(norm(grad_q)))),
        "diag/step": nan,
        "diag/advisor_gap": nan,
        "diag/q_gain": nan,
        "diag/saturated": jnp.mean(saturated.astype(actions.dtype)),
    }
    if targets is not None:
        gap = norm(advisor_actions - actions)
        count = jnp.sum(targets.replaced)
        gap_sum = jnp.sum(jnp.where(targets.replaced, gap, 0.0))
        out["diag/step"] = jnp.mean(norm(targets.step))
        out["diag/advisor_gap"] = jnp.where(count > 0, gap_sum / jnp.maximum(count, 1), jnp.nan)
        if afp:
            out["diag/q_gain"] = jnp.mean(targets.q_gain)
    return out
