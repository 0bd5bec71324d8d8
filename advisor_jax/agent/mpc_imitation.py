"""Imitation of a controller's actions by the actor: one Adam step on an MSE loss.

MCP + model-free (docs/baselines.md): the actor is fitted to the MPC's actions on the
states the MPC (then, DAgger, the actor itself) visited (``mbmf.py``: MSE, Adam lr 1e-3,
batch 512)::

    L = (1/n) Σ_i ‖π(s_i) − a_i‖²        (sum over V, ω: Eq. 3's form, update_rules)
    φ ← Adam(lr) step on L

Nothing in it is specific to the MPC: it is the generic behaviour-cloning step, the same
one LfD's imitation of the advisor needs, and should stay the one copy. The caller samples
the batch (e.g. uniformly from the valid rows of an imitation buffer) and scans the steps.
The learning rate may be traced (vmapped); Adam's state does not depend on it, so
``optax.adam(lr).init(params)`` with any ``lr`` builds ``opt_state``.
"""

from __future__ import annotations

from collections.abc import Callable
from typing import Any

import jax
import optax

from advisor_jax.agent.update_rules import mse_actor_loss


def imitation_step(
    actor_apply: Callable[[Any, jax.Array], jax.Array],
    params: Any,
    opt_state: Any,
    obs: jax.Array,
    labels: jax.Array,
    lr: jax.Array | float,
) -> tuple[Any, Any, jax.Array]:
    """One step on ``(obs [n, 20], labels [n, 2])``; returns (params, opt_state, loss)."""
    loss, grads = jax.value_and_grad(lambda p: mse_actor_loss(actor_apply(p, obs), labels))(params)
    updates, opt_state = optax.adam(lr).update(grads, opt_state, params)
    return optax.apply_updates(params, updates), opt_state, loss
