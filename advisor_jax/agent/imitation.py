"""Imitation of a demonstrator by the actor: behaviour cloning, one pure Adam step.

The LfD baseline (Pfeiffer et al., RA-L 2018; docs/baselines.md, "LfD") pre-trains the
actor on demonstrations before RL. Pfeiffer's imitation loss is not released; we use the
mean squared error that Nagabandi et al. (``mbmf.py``) and TD3+BC use, in the form of the
paper's Eq. (3) (R23: batch mean of the squared distance summed over V and ω)::

    L_BC(φ) = (1/n) Σ_i ‖π_φ(s_i) − a_i‖²        a_i: the demonstrator's clean action
    φ ← Adam(lr = bc_lr)(φ, ∇_φ L_BC)             lr 1e-3, batch 512 (``mbmf.py``)

The functions are of one agent and pure (jit / vmap at the call site); the learning rate is
traced (a baseline's vmappable ``bc_lr``, ``hparams.LfdHParams``), so the Adam
transformation is built inside the step as the learner's is. The Adam state is the
imitation's own: the RL phase starts from a fresh actor Adam state (docs/baselines.md, "RL
start").
"""

from __future__ import annotations

from typing import Any

import jax
import optax

from advisor_jax.agent.update_rules import mse_actor_loss


def imitation_init(actor_params: Any) -> Any:
    """A fresh Adam state for the actor's imitation (it does not depend on the lr)."""
    return optax.adam(1.0).init(actor_params)


def imitation_loss(actor, params: Any, obs: jax.Array, labels: jax.Array) -> jax.Array:
    """(1/n) Σ_i ‖π(s_i) − a_i‖² over a batch: obs [n, 20], labels [n, 2]."""
    return mse_actor_loss(actor.apply(params, obs), labels)


def imitation_step(
    actor, params: Any, opt_state: Any, obs: jax.Array, labels: jax.Array, lr: jax.Array | float
) -> tuple[Any, Any, dict[str, jax.Array]]:
    """One Adam step of ``imitation_loss``; returns (params, opt_state, metrics).

    Metrics: ``bc/loss`` (before the step) and ``bc/grad_norm``.
    """
    loss, grads = jax.value_and_grad(lambda p: imitation_loss(actor, p, obs, labels))(params)
    updates, opt_state = optax.adam(lr).update(grads, opt_state, params)
    params = optax.apply_updates(params, updates)
    return params, opt_state, {"bc/loss": loss, "bc/grad_norm": optax.global_norm(grads)}
