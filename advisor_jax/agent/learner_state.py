"""The learner's state and interface (``learner.make_learner`` builds it), and the metric
helpers its steps share."""

from __future__ import annotations

from collections.abc import Callable
from typing import Any, NamedTuple

import jax
import jax.numpy as jnp
from flax import struct

from advisor_jax.agent.config import HParams
from advisor_jax.agent.replay_buffer import Transition

Metrics = dict[str, jax.Array]


@struct.dataclass
class LearnerState:
    actor: Any  # φ
    critic: Any  # θ, stacked on a leading axis of n_critics (1 or 2)
    target_actor: Any  # φ^T
    target_critic: Any  # θ^T, same layout as ``critic``
    actor_opt: Any  # Adam state of φ (agent/adam.py; on GPUs bf16 learners store m, v in bf16)
    critic_opt: Any  # optax Adam state of θ (likewise)
    critic_updates: jax.Array  # int32, t of Alg. A3
    actor_updates: jax.Array  # int32
    target_nets: Any = None
    """(target actor, target critics) as the learner's networks compute them
    (``networks.NetworkFunctions.build``: ``gemm_layers``' augmented matrices), built once per
    soft update instead of once per critic step; the critics None where ``held`` has them.
    Held only inside a training chunk (``Learner.hold`` at its start, ``release`` at its
    end), so that a stored state (a chunk's input and output, a checkpoint) is the same
    whatever the device; None there, and where the flax modules compute (whose build is the
    parameters themselves)."""
    held: Any = None
    """``held_critics.HeldCritics``: inside a chunk, with ``Layout.held_critics``, θ, θ^T and
    their Adam state as the matrices the GEMMs read (``critic``, ``target_critic`` and
    ``critic_opt`` None meanwhile); None elsewhere."""


class Learner(NamedTuple):
    init: Callable[[jax.Array], LearnerState]
    """(key) -> LearnerState: He init, targets = copies (Alg. 2 step 4, Alg. A3 step 5)."""
    q_select: Callable[[LearnerState, jax.Array, jax.Array], jax.Array]
    """(state, obs [..., 20], action [..., 2]) -> Q [...] for the Eq. (1) selector, at fp32:
    the min over the critics (Alg. A2 steps 11-12); Q itself for one critic."""
    sample: Callable[[Any, jax.Array], Transition]
    """(replay, key) -> B: ``batch_size`` transitions drawn uniformly, with replacement."""
    critic_step: Callable[[LearnerState, Transition, jax.Array, HParams], tuple[Any, Metrics]]
    """(state, batch, key, hp) -> (state, metrics): one critic update."""
    actor_step: Callable[..., tuple[Any, Metrics]]
    """(state, batch, hp, episode=0) -> (state, metrics): one actor update and the soft update
    of all targets; ``episode`` (episodes completed) gates the AfP replacement by N_P."""
    update: Callable[..., tuple[Any, Metrics, jax.Array]]
    """(state, batch, critic_key, hp, update_index, episode=0) -> (state, metrics,
    nonfinite): one whole update on ``batch`` (from ``sample``), its delayed actor step
    decided from ``update_index`` (see ``make_learner``)."""
    update_with_actor: Callable[..., tuple[Any, Metrics, jax.Array]]
    """(state, batch, critic_key, hp, episode=0) -> as ``update`` at an index
    that takes the actor step, with no conditional."""
    update_critic_only: Callable[..., tuple[Any, Metrics, jax.Array]]
    """(state, batch, critic_key, hp, episode=0) -> as ``update`` at an index
    that skips it, with no conditional."""
    hold: Callable[[LearnerState], LearnerState]
    """(state) -> the state holding its target networks built (``LearnerState.target_nets``)
    and, with ``Layout.held_critics``, its critics as matrices (``LearnerState.held``);
    unchanged where the flax modules compute. The steps that follow read them, and every
    soft update builds the targets again. The same updates (bit for bit under XLA's defaults)."""
    release: Callable[[LearnerState], LearnerState]
    """(state) -> the state as it is stored: flax trees, nothing held."""


def nan_like(shapes: Any) -> Any:
    """NaN (floats) or zero (integers) arrays of the given shapes: "not computed"."""
    fill = lambda s: jnp.full(  # noqa: E731
        s.shape, jnp.nan if jnp.issubdtype(s.dtype, jnp.floating) else 0, s.dtype
    )
    return jax.tree.map(fill, shapes)


def all_finite(metrics: Metrics) -> jax.Array:
    """Whether every loss, Q estimate and gradient norm is finite (``diag/`` may be NaN)."""
    values = [v for name, v in metrics.items() if not name.startswith("diag/")]
    return jnp.all(jnp.stack([jnp.all(jnp.isfinite(v)) for v in values]))
