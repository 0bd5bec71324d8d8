"""Update rules of DDPG, ADDPG (Alg. 2), TD3 and ATD3 (Alg. A3), with the advisor (AfP).

One implementation, configured by ``AgentConfig`` (``algo``, ``advisor_policy``).
``Learner.update`` is the one update step that training, the learner benchmark and the
tests run: it samples a batch B from the replay buffer, calls ``critic_step`` and then,
every ``cfg.delay``-th update (every update for the DDPG family), ``actor_step`` on the
same batch with the freshly updated critic (Alg. 2 steps 6-15, Alg. A3 steps 9-22)::

    critic_step(B):                                     # Alg. 2 steps 7-8, Alg. A3 10-14
        A' = π^T(S')                                    # DDPG / ADDPG, Eq. (4)
        A' = clip(π^T(S') + clip(N(0, σ̄), -c, c), box)  # TD3 / ATD3
        Q̂  = R + γ (1 - terminal) min_k Q_k^T(S', A')   # one critic: min is Q^T
        Q̂  = clip(Q̂, lo, hi)                            # only with clip_q_target = 1 (R35)
        L_Q = Σ_k (1/n) Σ_i (Q̂_i - Q_k(s_i, a_i))²      # Eq. (5) with Q(S, A), see below
    actor_step(B):                                      # Alg. 2 steps 9-15, Alg. A3 16-22
        DDPG / TD3:   L_π = -(1/n) Σ_i Q_1(s_i, π(s_i))                 # DPG
        ADDPG / ATD3: A_act = π(S);  Â = A_act + β ∇_a Q_1(S, A_act)     # Eq. (2)
                      AfP: Â_i ← a_adv,i where Q_1(s_i, a_adv,i) > Q_1(s_i, Â_i)
                      L_π = (1/n) Σ_i ||stop_grad(Â_i) - π(s_i)||²       # Eq. (3)
        φ^T ← τφ + (1-τ)φ^T;  θ_k^T ← τθ_k + (1-τ)θ_k^T                  # Eqs. (6), (7)

Choices where the paper is loose, all standard:

* Eq. (5) prints Q(S, π(S); θ) inside the critic loss; Alg. 2 step 8 and Alg. A3 steps
  13-14 use the replayed action, Q(S, A; θ), which is the TD loss we implement.
* TD3's smoothed target action A' is clipped to the action box (V ∈ [0, 1], ω ∈ [-1, 1]);
  Alg. A3 step 11 omits it, TD3 (Fujimoto et al.) has it. The noise is N(μ = 0, σ̄) per
  sample and action dimension (Table A4: μ = 0).
* A terminal transition (goal, collision) does not bootstrap; a timeout does (the
  paper's Q̂ has no (1 - terminal) factor but its episodes are finite).
* Â is not clipped to the action box by default: Eq. (2) does not, and the actor's
  sigmoid/tanh head keeps π(S) inside the box whatever Â is (``clip_actor_target`` = 1
  clips it; see below).
* Twin critics are one params tree with a leading axis (``networks.init_critics``), one
  loss (the sum of the per-critic losses, so each critic gets its own gradient) and one
  Adam. Q_1 (index 0) drives the actor (Alg. A3 step 17) and the AfP mask (step 19).
* ``HParams.advisor_policy_episodes`` (N_P, ours) turns the AfP replacement off once the
  agent has completed more than N_P episodes (``actor_step``'s ``episode``), as N_T does
  for the advisor in data collection; its default (10^9) keeps the paper's Alg. 2.
* Learning rates are traced (``HParams``), so the Adam transformations are built inside
  the step functions; their state structure does not depend on the learning rate.

Metrics (flat dicts of scalars, the same keys for every algorithm): ``critic_step`` gives
``loss/critic`` (mean over critics), ``q/mean`` (Q(S, A) over critics and batch),
``q/target`` (mean Q̂) and ``grad_norm/critic``; ``actor_step`` gives ``loss/actor``,
``advisor/replaced`` (fraction of the batch where AfP replaced Â; 0 without AfP and for
DDPG/TD3), ``grad_norm/actor`` and the diagnostics of ``diagnostics.actor_diagnostics``
(``diag/...``: ∇_aQ scale, Eq. 2 step, advisor gap, Q gain, saturated heads). A
non-finite loss, Q or gradient norm marks the agent diverged; a ``diag/`` value may be NaN
(not defined).

Three readings are selectable per agent, as hyperparameters (0 = the paper, the default):
``beta_normalize`` makes Eq. (2)'s step scale-free (``update_rules.eq2_step``),
``clip_actor_target`` clips Â to the action box before AfP compares and the actor regresses
on it, and ``clip_q_target`` clips the TD target Q̂ into the bounds of every achievable
return, [lo, hi] = ``return_bounds(γ)`` (``envs.reward.return_bounds``, passed to
``make_learner`` by the trainer; without it the switch has nothing to clip to). The critic
metrics then include ``q/clipped``, the fraction of the batch's targets the clip changed.
"""

from __future__ import annotations

from collections.abc import Callable
from typing import Any, NamedTuple

import jax
import jax.numpy as jnp
import optax
from flax import struct

from advisor_jax.agent.config import AgentConfig, HParams
from advisor_jax.agent.diagnostics import actor_diagnostics
from advisor_jax.agent.networks import (
    MODULES,
    Layout,
    apply_critics,
    init_actor,
    init_critics,
    learner_functions,
    make_actor,
    make_critic,
)
from advisor_jax.agent.replay_buffer import ReplayState, Transition, replay_sample
from advisor_jax.agent.update_rules import (
    addpg_actor_targets,
    bounded_targets,
    critic_losses,
    critic_targets,
    dpg_actor_loss,
    mse_actor_loss,
    smoothed_target_actions,
    soft_update,
)

Metrics = dict[str, jax.Array]


@struct.dataclass
class LearnerState:
    actor: Any  # φ
    critic: Any  # θ, stacked on a leading axis of n_critics (1 or 2)
    target_actor: Any  # φ^T
    target_critic: Any  # θ^T, same layout as ``critic``
    actor_opt: Any  # optax Adam state of φ (m in bf16: Layout.bf16_first_moment)
    critic_opt: Any  # optax Adam state of θ (likewise)
    critic_updates: jax.Array  # int32, t of Alg. A3
    actor_updates: jax.Array  # int32
    target_nets: Any = None
    """(target actor, target critics) as the learner's networks compute them
    (``networks.NetworkFunctions.build``: ``gemm_layers``' augmented matrices), built once per
    soft update instead of once per critic step. Held only inside a training chunk
    (``Learner.hold_targets`` at its start, ``drop_targets`` at its end), so that a stored
    state (a chunk's input and output, a checkpoint) is the same whatever the device; None
    there, and where the flax modules compute (whose build is the parameters themselves)."""


class Learner(NamedTuple):
    init: Callable[[jax.Array], LearnerState]
    """(key) -> LearnerState: He init, targets = copies (Alg. 2 step 4, Alg. A3 step 5)."""
    q_select: Callable[[Any, jax.Array, jax.Array], jax.Array]
    """(critic params, obs [..., 20], action [..., 2]) -> Q [...] for the Eq. (1) selector:
    the min over the critics (Alg. A2 steps 11-12); Q itself for one critic."""
    critic_step: Callable[[LearnerState, Transition, jax.Array, HParams], tuple[Any, Metrics]]
    """(state, batch, key, hp) -> (state, metrics): one critic update."""
    actor_step: Callable[..., tuple[Any, Metrics]]
    """(state, batch, hp, episode=0) -> (state, metrics): one actor update and the soft update
    of all targets; ``episode`` (episodes completed) gates the AfP replacement by N_P."""
    update: Callable[..., tuple[Any, Metrics, jax.Array]]
    """(state, replay, sample_key, critic_key, hp, update_index, episode=0) -> (state,
    metrics, nonfinite): one whole update, its delayed actor step decided from
    ``update_index`` (see ``make_learner``)."""
    update_with_actor: Callable[..., tuple[Any, Metrics, jax.Array]]
    """(state, replay, sample_key, critic_key, hp, episode=0) -> as ``update`` at an index
    that takes the actor step, with no conditional."""
    update_critic_only: Callable[..., tuple[Any, Metrics, jax.Array]]
    """(state, replay, sample_key, critic_key, hp, episode=0) -> as ``update`` at an index
    that skips it, with no conditional."""
    hold_targets: Callable[[LearnerState], LearnerState]
    """(state) -> the state holding its target networks built (``LearnerState.target_nets``;
    unchanged where the flax modules compute): the critic steps that follow read them, and
    every soft update builds them again. The same updates (bit for bit under XLA's defaults)."""
    drop_targets: Callable[[LearnerState], LearnerState]
    """(state) -> the state without them (``target_nets`` None), as it is stored."""


def _first_critic(critic_params: Any) -> Any:
    return jax.tree.map(lambda x: x[0], critic_params)


# The learner ----------------------------------------------------------------------------


def make_learner(
    cfg: AgentConfig,
    return_bounds: Callable[[jax.Array], tuple[jax.Array, jax.Array]] | None = None,
    layout: Layout = MODULES,
) -> Learner:
    """Init, selector Q and the two update steps for one agent type (pure, jit/vmap-able).

    ``return_bounds``: γ -> (lo, hi), the interval of every achievable discounted return
    (``functools.partial(envs.reward.return_bounds, env.config)``); the critic clips Q̂ into
    it for agents with ``clip_q_target`` = 1. None: no clipping whatever the switch says.
    ``layout``: how the networks are computed (``networks.Layout``), which the program that
    runs the learner chooses (``training.program.network_layout``): the twin critics' input
    layout of all this learner's critics, its fp32 acting critic too; whether the learner's
    networks run as ``gemm_layers`` (each hidden layer one GEMM with its bias inside) instead
    of the flax modules, acting (the Eq. 1 selector's Q) keeping the modules; and whether a
    bf16 learner's Adam keeps its first moment in bf16 (``Layout.bf16_first_moment``).

    Long: the factory of the learner's closures (init, selector Q, the two steps, the
    three whole updates and the held targets), which share its networks and settings; each
    is short.
    """
    if not isinstance(cfg, AgentConfig):
        raise TypeError(f"make_learner needs an AgentConfig, got {type(cfg).__name__}")
    actor = make_actor(cfg.actor_hidden, cfg.precision)
    critic = make_critic(cfg, cfg.precision)
    critic_fp32 = make_critic(cfg)  # the Eq. (1) selector acts: always fp32
    per_critic = layout.inputs_per_critic
    actor_net, critic_net = learner_functions(actor, critic, layout)
    mu_dtype = jnp.bfloat16 if layout.bf16_first_moment and cfg.precision == "bf16" else None

    def adam(learning_rate: jax.Array | float) -> optax.GradientTransformation:
        return optax.adam(learning_rate, mu_dtype=mu_dtype)  # lr: a traced hyperparameter

    def build_targets(state: LearnerState) -> tuple[Any, Any]:
        return actor_net.build(state.target_actor), jax.vmap(critic_net.build)(state.target_critic)

    def hold_targets(state: LearnerState) -> LearnerState:
        return state.replace(target_nets=build_targets(state)) if layout.layers_in_gemm else state

    def drop_targets(state: LearnerState) -> LearnerState:
        return state.replace(target_nets=None)

    def init(key: jax.Array) -> LearnerState:
        key_actor, key_critic = jax.random.split(key)
        actor_params = init_actor(actor, key_actor)
        critic_params = init_critics(critic, key_critic, cfg.n_critics)
        return LearnerState(
            actor=actor_params,
            critic=critic_params,
            # Copies, not aliases: an eager init would otherwise hand the same buffers to
            # online and target, and donating the state to a jitted step would then fail.
            target_actor=jax.tree.map(jnp.copy, actor_params),
            target_critic=jax.tree.map(jnp.copy, critic_params),
            # Adam's state (count, μ, ν) does not depend on the learning rate.
            actor_opt=adam(1.0).init(actor_params),
            critic_opt=adam(1.0).init(critic_params),
            critic_updates=jnp.int32(0),
            actor_updates=jnp.int32(0),
        )

    def q_select(critic_params: Any, obs: jax.Array, action: jax.Array) -> jax.Array:
        q = apply_critics(critic_fp32.apply, critic_params, obs, action, per_critic)
        return jnp.min(q, axis=0)

    def critic_step(
        state: LearnerState, batch: Transition, key: jax.Array, hp: HParams
    ) -> tuple[LearnerState, Metrics]:
        held = state.target_nets is not None  # static: the state's structure
        target_actor, target_critics = state.target_nets if held else build_targets(state)
        next_actions = actor_net.forward(target_actor, batch.next_obs)  # [n, 2]
        if cfg.twin:
            next_actions = smoothed_target_actions(
                key, next_actions, hp.target_noise, hp.target_noise_clip
            )
        next_q = apply_critics(
            critic_net.forward, target_critics, batch.next_obs, next_actions, per_critic
        )
        targets = critic_targets(batch.reward, batch.terminal, next_q, hp.gamma)  # [n]
        clipped = jnp.zeros((), jnp.float32)
        if return_bounds is not None:
            bounded = bounded_targets(targets, *return_bounds(hp.gamma), hp.clip_q_target)
            clipped = jnp.mean((bounded != targets).astype(jnp.float32))
            targets = bounded

        def loss_fn(params):
            # [n_critics, n]
            q = apply_critics(critic_net.apply, params, batch.obs, batch.action, per_critic)
            losses = critic_losses(q, targets)
            return jnp.sum(losses), (losses, q)

        (_, (losses, q)), grads = jax.value_and_grad(loss_fn, has_aux=True)(state.critic)
        updates, critic_opt = adam(hp.lr_critic).update(grads, state.critic_opt, state.critic)
        new_state = state.replace(
            critic=optax.apply_updates(state.critic, updates),
            critic_opt=critic_opt,
            critic_updates=state.critic_updates + 1,
        )
        metrics = {
            "loss/critic": jnp.mean(losses),
            "q/mean": jnp.mean(q),
            "q/target": jnp.mean(targets),
            "q/clipped": clipped,
            "grad_norm/critic": optax.global_norm(grads),
        }
        return new_state, metrics

    def actor_step(
        state: LearnerState, batch: Transition, hp: HParams, episode: jax.Array | int = 0
    ) -> tuple[LearnerState, Metrics]:
        q1_params = _first_critic(state.critic)

        def q1(obs, action):
            return critic_net.apply(q1_params, obs, action)

        # One actor forward; the loss is differentiated w.r.t. the actions and pulled back.
        actions, pullback = jax.vjp(lambda p: actor_net.apply(p, batch.obs), state.actor)
        if cfg.advisor_target:
            targets = addpg_actor_targets(
                q1,
                batch.obs,
                actions,
                batch.advisor_action,
                hp.beta,
                cfg.advisor_policy,
                replace_allowed=episode <= hp.advisor_policy_episodes,
                normalize=hp.beta_normalize,
                clip_target=hp.clip_actor_target,
            )
            loss, dloss = jax.value_and_grad(mse_actor_loss)(actions, targets.a_hat)
            replaced, grad_q = targets.replaced, targets.grad_q
        else:
            replaced = jnp.zeros(actions.shape[:-1], bool)
            loss, dloss = jax.value_and_grad(lambda a: dpg_actor_loss(q1, batch.obs, a))(actions)
            grad_q = -dloss * actions.shape[0]  # the DPG loss is -(1/n) Σ Q: dloss = -∇_aQ / n
            targets = None
        diagnostics = actor_diagnostics(
            actions, batch.advisor_action, grad_q, targets, cfg.advisor_policy
        )
        (grads,) = pullback(dloss)
        updates, actor_opt = adam(hp.lr_actor).update(grads, state.actor_opt, state.actor)
        actor_params = optax.apply_updates(state.actor, updates)
        new_state = state.replace(
            actor=actor_params,
            actor_opt=actor_opt,
            target_actor=soft_update(state.target_actor, actor_params, hp.tau),
            target_critic=soft_update(state.target_critic, state.critic, hp.tau),
            actor_updates=state.actor_updates + 1,
        )
        if state.target_nets is not None:
            new_state = hold_targets(new_state)  # the soft update changed them
        metrics = {
            "loss/actor": loss,
            "advisor/replaced": jnp.mean(replaced.astype(jnp.float32)),
            "grad_norm/actor": optax.global_norm(grads),
            **diagnostics,
        }
        return new_state, metrics

    def sample_and_critic(state, replay, sample_key, critic_key, hp):
        with jax.named_scope("replay_sample"):  # scopes: labels for profiles, nothing else
            batch = replay_sample(replay, sample_key, cfg.batch_size)
        with jax.named_scope("critic_step"):
            state, critic_metrics = critic_step(state, batch, critic_key, hp)
        return state, batch, critic_metrics

    def skip_actor(state, batch, hp, episode):
        return state, nan_like(jax.eval_shape(actor_step, state, batch, hp, episode)[1])

    def finish(state, critic_metrics, actor_metrics, took_actor):
        nonfinite = ~_all_finite(critic_metrics) | (took_actor & ~_all_finite(actor_metrics))
        return state, {**critic_metrics, **actor_metrics}, nonfinite

    def update(
        state: LearnerState,
        replay: ReplayState,
        sample_key: jax.Array,
        critic_key: jax.Array,
        hp: HParams,
        update_index: jax.Array | int,
        episode: jax.Array | int = 0,
    ) -> tuple[LearnerState, Metrics, jax.Array]:
        """One update (Alg. 2 steps 6-15, Alg. A3 steps 9-22): sample, critic, delayed actor.

        Args:
          sample_key: draws the batch; critic_key: TD3's target smoothing noise.
          update_index: global index of this update; the actor step runs when
            ``update_index % d == 0`` (``lax.cond``). Pass it *unbatched* under ``vmap``:
            the test then stays a scalar and the cond really skips the actor step instead
            of computing and selecting it.
          episode: episodes the agent has completed (the N_P gate of ``actor_step``).

        Returns:
          The new state; the critic and actor metrics (the actor's NaN on updates that
          skip it); and whether any loss computed in this update was non-finite.
        """
        state, batch, critic_metrics = sample_and_critic(state, replay, sample_key, critic_key, hp)
        with jax.named_scope("actor_step"):
            took_actor = update_index % cfg.delay == 0
            state, actor_metrics = jax.lax.cond(
                took_actor,
                lambda s: actor_step(s, batch, hp, episode),
                lambda s: skip_actor(s, batch, hp, episode),
                state,
            )
        return finish(state, critic_metrics, actor_metrics, took_actor)

    def update_with_actor(state, replay, sample_key, critic_key, hp, episode=0):
        """``update`` at an index where the delay takes the actor step, compiled with no
        conditional (a caller that knows the schedule statically: the steady program of
        ``training.train``, which a GPU runs as one graph of overlapping kernels)."""
        state, batch, critic_metrics = sample_and_critic(state, replay, sample_key, critic_key, hp)
        with jax.named_scope("actor_step"):
            state, actor_metrics = actor_step(state, batch, hp, episode)
        return finish(state, critic_metrics, actor_metrics, jnp.ones((), bool))

    def update_critic_only(state, replay, sample_key, critic_key, hp, episode=0):
        """``update`` at an index where the delay skips the actor step, with no conditional
        (as ``update_with_actor``); the actor metrics are NaN."""
        state, batch, critic_metrics = sample_and_critic(state, replay, sample_key, critic_key, hp)
        with jax.named_scope("actor_step"):
            state, actor_metrics = skip_actor(state, batch, hp, episode)
        return finish(state, critic_metrics, actor_metrics, jnp.zeros((), bool))

    return Learner(
        init=init,
        q_select=q_select,
        critic_step=critic_step,
        actor_step=actor_step,
        update=update,
        update_with_actor=update_with_actor,
        update_critic_only=update_critic_only,
        hold_targets=hold_targets,
        drop_targets=drop_targets,
    )


def nan_like(shapes: Any) -> Any:
    """NaN (floats) or zero (integers) arrays of the given shapes: "not computed"."""
    fill = lambda s: jnp.full(  # noqa: E731
        s.shape, jnp.nan if jnp.issubdtype(s.dtype, jnp.floating) else 0, s.dtype
    )
    return jax.tree.map(fill, shapes)


def _all_finite(metrics: Metrics) -> jax.Array:
    """Whether every loss, Q estimate and gradient norm is finite (``diag/`` may be NaN)."""
    values = [v for name, v in metrics.items() if not name.startswith("diag/")]
    return jnp.all(jnp.stack([jnp.all(jnp.isfinite(v)) for v in values]))
