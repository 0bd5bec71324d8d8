"""The update rules of Alg. 2 / A3 as pure functions on arrays (no networks, no optimiser).

``learner.make_learner`` composes them into the critic and actor steps; the tests check
each one against hand-computed values. Equations as in ``learner``'s docstring.
"""

from __future__ import annotations

from collections.abc import Callable
from typing import Any, NamedTuple

import jax
import jax.numpy as jnp

from advisor_jax.contract import spec

QFn = Callable[[jax.Array, jax.Array], jax.Array]  # (obs [..., 20], action [..., 2]) -> Q [...]


def soft_update(target: Any, online: Any, tau: jax.Array | float) -> Any:
    """Eqs. (6), (7): target ← τ·online + (1 - τ)·target, leaf by leaf."""
    return jax.tree.map(lambda t, o: tau * o + (1.0 - tau) * t, target, online)


def clip_action(action: jax.Array) -> jax.Array:
    """Clips ``[..., 2]`` actions to the box V ∈ [0, 1], ω ∈ [-1, 1] (``contract/spec.py``)."""
    low = jnp.asarray(spec.ACTION_LOW, action.dtype)
    high = jnp.asarray(spec.ACTION_HIGH, action.dtype)
    return jnp.clip(action, low, high)


def smoothed_target_actions(
    key: jax.Array,
    target_actions: jax.Array,
    sigma: jax.Array | float,
    noise_clip: jax.Array | float,
) -> jax.Array:
    """TD3 target smoothing (Alg. A3 steps 10-11): clip(π^T(S') + clip(σ̄ξ, -c, c), box)."""
    noise = sigma * jax.random.normal(key, target_actions.shape, target_actions.dtype)
    return clip_action(target_actions + jnp.clip(noise, -noise_clip, noise_clip))


def critic_targets(
    reward: jax.Array, terminal: jax.Array, next_q: jax.Array, gamma: jax.Array | float
) -> jax.Array:
    """Q̂ = R + γ(1 - terminal)·min_k next_q[k] (Eq. 4; Alg. A3 step 12).

    Args:
      reward, terminal: [n].
      next_q: [n_critics, n] target critics at (S', A'); the min over one critic is itself.
    """
    return reward + gamma * (1.0 - terminal) * jnp.min(next_q, axis=0)


def bounded_targets(
    targets: jax.Array, low: jax.Array | float, high: jax.Array | float, clip
) -> jax.Array:
    """Q̂ clipped into [low, high] where the traced 0/1 switch ``clip`` is 1, else Q̂ itself.

    With the bounds of every achievable return (``envs.reward.return_bounds``) this cuts the
    feedback by which one critic's overestimate, bootstrapped through Q̂, grows without limit
    (HER, Andrychowicz et al. 2017, clips its targets to the return range the same way).
    """
    return jnp.where(clip > 0, jnp.clip(targets, low, high), targets)


def critic_losses(q: jax.Array, targets: jax.Array) -> jax.Array:
    """Per-critic TD loss (1/n) Σ_i (Q̂_i - Q_k(s_i, a_i))²: q [n_critics, n] → [n_critics]."""
    return jnp.mean(jnp.square(jax.lax.stop_gradient(targets) - q), axis=-1)


class ActorTargets(NamedTuple):
    """``addpg_actor_targets``'s result: the regression target and what went into it."""

    a_hat: jax.Array  # [n, 2] Â after clipping and the AfP replacement (no gradient)
    replaced: jax.Array  # [n] bool, AfP replaced â_i by a_adv,i
    grad_q: jax.Array  # [n, 2] ∇_a Q_1(s_i, π(s_i))
    step: jax.Array  # [n, 2] the Eq. (2) step added to π(S) (β∇_aQ, or its scale-free form)
    q_gain: jax.Array  # [n] Q(s_i, a_adv,i) - Q(s_i, â_i) before replacement (0 without AfP)


def eq2_step(grad_q: jax.Array, beta, normalize) -> jax.Array:
    """The step of Eq. (2) added to π(S): β ∇_aQ, or, with ``normalize`` = 1, scale-free.

    Literal (``normalize`` = 0, the paper): ``β ∇_aQ``. Its length depends on the scale of
    this environment's Q and of ∇_aQ, so a β tuned for one reward scale or one stage of
    training does not transfer (docs/architecture.md, "Agents").

    Scale-free (``normalize`` = 1): ``β ∇_aQ / rms_i ‖∇_aQ(s_i)‖``, the batch's ∇_aQ scaled
    to unit root-mean-square length, so β is the mean step in normalised action units (the
    action box is 1 × 2 wide) whatever the Q scale; the direction per sample, and the
    relative sizes within the batch, stay those of ∇_aQ. Like TD3+BC's λ = α / mean|Q|, the
    scale is a batch statistic with no gradient. ``normalize`` is a traced 0/1 so that one
    vmapped sweep can hold both forms.
    """
    rms = jnp.sqrt(jnp.mean(jnp.sum(jnp.square(grad_q), axis=-1)))
    scale = jnp.where(normalize > 0, 1.0 / jnp.maximum(rms, 1e-12), 1.0)
    return jax.lax.stop_gradient(beta * scale) * grad_q


def addpg_actor_targets(
    q_fn: QFn,
    obs: jax.Array,
    actor_actions: jax.Array,
    advisor_actions: jax.Array,
    beta: jax.Array | float,
    advisor_policy: bool,
    replace_allowed: jax.Array | bool = True,
    normalize: jax.Array | float = 0.0,
    clip_target: jax.Array | float = 0.0,
) -> ActorTargets:
    """Â of Eq. (2) with the AfP replacement (Alg. 2 steps 9-13).

    Args:
      q_fn: Q_1 with its params bound, (obs [n, 20], action [n, 2]) -> [n].
      obs: [n, 20]; actor_actions: [n, 2] = π(S); advisor_actions: [n, 2] = A_adv.
      beta: β of Eq. (2).
      advisor_policy: static; AfP on (steps 11-13) or off (plain ADDPG).
      replace_allowed: traced bool; False turns the replacement off for this update (our
        ``advisor_policy_episodes`` N_P; the paper always replaces).
      normalize: traced 0/1; 1 makes the Eq. (2) step scale-free (``eq2_step``).
      clip_target: traced 0/1; 1 clips â to the action box before it is compared with the
        advisor's action and regressed on (the paper does neither: Eq. (2) as printed can
        ask the sigmoid/tanh heads for values they cannot reach).

    Returns:
      ``ActorTargets``: â (the advisor's action where Q(s_i, a_adv,i) > Q(s_i, â_i) and AfP
      replaced it), the replacement mask, ∇_aQ, the step, and Q(s, a_adv) - Q(s, â).
    """
    actor_actions = jax.lax.stop_gradient(actor_actions)
    # Samples are independent, so the gradient of the batch sum is the per-sample ∇_a Q.
    grad_q = jax.grad(lambda a: jnp.sum(q_fn(obs, a)))(actor_actions)  # [n, 2]
    step = eq2_step(grad_q, beta, normalize)
    a_hat = actor_actions + step
    a_hat = jnp.where(clip_target > 0, clip_action(a_hat), a_hat)
    if not advisor_policy:
        no = jnp.zeros(a_hat.shape[:-1], bool)
        return ActorTargets(a_hat, no, grad_q, step, jnp.zeros(a_hat.shape[:-1], a_hat.dtype))
    # One critic call on [2, n] rather than two on [n].
    q_hat, q_adv = q_fn(jnp.stack([obs, obs]), jnp.stack([a_hat, advisor_actions]))
    replaced = (q_adv > q_hat) & replace_allowed  # [n]
    a_hat = jnp.where(replaced[:, None], advisor_actions, a_hat)
    return ActorTargets(jax.lax.stop_gradient(a_hat), replaced, grad_q, step, q_adv - q_hat)


def mse_actor_loss(actions: jax.Array, a_hat: jax.Array) -> jax.Array:
    """Eq. (3): (1/n) Σ_i ||stop_grad(â_i) - π(s_i)||² (sum over the 2 action dimensions)."""
    return jnp.mean(jnp.sum(jnp.square(jax.lax.stop_gradient(a_hat) - actions), axis=-1))


def dpg_actor_loss(q_fn: QFn, obs: jax.Array, actions: jax.Array) -> jax.Array:
    """Deterministic policy gradient loss -(1/n) Σ_i Q(s_i, π(s_i)) (DDPG, TD3)."""
    return -jnp.mean(q_fn(obs, actions))
