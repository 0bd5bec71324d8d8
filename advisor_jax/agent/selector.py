"""The selector of the advisor architecture: Eq. (1) / (A1), and Eq. (11) (Appendix D).

Eq. (1), per step and per environment (Alg. 1 steps 11-12; Alg. A2 steps 11-14)::

    ε = 1               if Q_act <= Q_adv and N <= N_T
        ε_st - b N      if Q_act >  Q_adv and N <= N_T
        0               if N > N_T
    ε = clip(ε, 0, 1)
    a = a_adv with probability ε, else a_act

N is the agent's completed-episode count (docs/architecture.md, "Paper readings" R14), so
the first episode has N = 0 and the advisor still takes part while N = N_T. The clip keeps
ε a probability when ε_st - bN becomes negative for large N (the paper's b = 0.15 read per
episode), and when a sweep that skipped ``config.validate_hparams`` passes ε_st > 1 or
b < 0. For ATD3 the trainer passes Q = min(Q1, Q2) (Alg. A2 steps 11-12;
``Learner.q_select`` does that). When AfD is off the trainer never calls this.

Eq. (11), the actor's expected maximum firing rate, is the moving average over a window of
w episodes of the upper bound bN + 1 - ε_st (Appendix D)::

    E(fr_max) = (1/w) Σ_{i=N-w+1}^{N} (b i + 1 - ε_st) = bN + 1 - ε_st - (b/2)(w - 1)

It is returned unclipped, exactly as printed; it is meaningful for w - 1 <= N <= N_T and
while bN <= ε_st.
"""

from __future__ import annotations

import jax
import jax.numpy as jnp

from advisor_jax.agent.config import HParams


def advisor_probability(
    q_actor: jax.Array, q_advisor: jax.Array, episode: jax.Array, hp: HParams
) -> jax.Array:
    """ε of Eq. (1), clipped to [0, 1]; shape of ``q_actor`` broadcast with ``episode``."""
    decayed = hp.eps_start - hp.eps_decay * episode
    eps = jnp.where(q_actor <= q_advisor, 1.0, decayed)
    eps = jnp.where(episode > hp.advisor_episodes, 0.0, eps)
    return jnp.clip(eps, 0.0, 1.0)


def select_action(
    key: jax.Array,
    actor_action: jax.Array,
    advisor_action: jax.Array,
    q_actor: jax.Array,
    q_advisor: jax.Array,
    episode: jax.Array,
    hp: HParams,
) -> tuple[jax.Array, jax.Array]:
    """Eq. (1) selection: ``(action [..., 2], used_advisor [...] bool)``.

    ``u < ε`` with ``u ~ U[0, 1)`` fires the advisor with probability exactly ε, always
    for ε = 1 and never for ε = 0.
    """
    eps = advisor_probability(q_actor, q_advisor, episode, hp)  # [...]
    used_advisor = jax.random.uniform(key, jnp.shape(eps)) < eps
    action = jnp.where(used_advisor[..., None], advisor_action, actor_action)
    return action, used_advisor


def expected_max_firing_rate(
    episode: jax.Array, eps_start: jax.Array, eps_decay: jax.Array, window: int | jax.Array
) -> jax.Array:
    """Eq. (11): E(fr_max) = bN + 1 - ε_st - (b/2)(w - 1) (unclipped, see module doc)."""
    episode = jnp.asarray(episode, jnp.float32)
    return eps_decay * episode + 1.0 - eps_start - 0.5 * eps_decay * (window - 1.0)
