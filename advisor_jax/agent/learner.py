"""Update rules of DDPG, ADDPG (Alg. 2), TD3 and ATD3 (Alg. A3), with the advisor (AfP).

One implementation, configured by ``AgentConfig`` (``algo``, ``advisor_policy``).
``Learner.update`` is the one update step that training, the learner benchmark and the
tests run: on a batch B drawn from the replay buffer (``Learner.sample``), it calls
``critic_step`` and then, every ``cfg.delay``-th update (every update for the DDPG family),
``actor_step`` on the same batch with the freshly updated critic (Alg. 2 steps 6-15, Alg. A3
steps 9-22)::

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
from typing import Any

import jax
import jax.numpy as jnp
import optax

from advisor_jax.agent import adam as optimizer
from advisor_jax.agent import held_critics
from advisor_jax.agent.config import AgentConfig, HParams
from advisor_jax.agent.diagnostics import actor_diagnostics
from advisor_jax.agent.learner_state import Learner, LearnerState, Metrics, all_finite, nan_like
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
    bf16 learner's Adam keeps its moments in bf16 (``Layout.bf16_first_moment``,
    ``bf16_second_moment``: ``agent/adam.py``).

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
    bf16 = cfg.precision == "bf16"
    mu_dtype = jnp.bfloat16 if layout.bf16_first_moment and bf16 else None
    nu_bf16 = layout.bf16_second_moment and bf16
    holds_critics = layout.held_critics and layout.layers_in_gemm
    critics_shape = structure = None
    if holds_critics:  # the held matrices' layout, read from the critics' shapes
        critics_shape = jax.eval_shape(lambda k: init_critics(critic, k, cfg.n_critics),
                                       jax.random.key(0))  # fmt: skip
        one = jax.tree.map(lambda x: jax.ShapeDtypeStruct(x.shape[1:], x.dtype), critics_shape)
        structure = held_critics.structure(one, layout.hidden_align)

    def adam(learning_rate: jax.Array | float) -> optax.GradientTransformation:
        return optimizer.adam(learning_rate, mu_dtype, nu_bf16)  # lr: a traced hyperparameter

    def build_targets(state: LearnerState) -> tuple[Any, Any]:
        held = state.held is not None
        critics = None if held else jax.vmap(critic_net.build)(state.target_critic)
        return actor_net.build(state.target_actor), critics

    def hold(state: LearnerState) -> LearnerState:
        if not layout.layers_in_gemm:
            return state
        if holds_critics:
            in_dtype = layout.bf16_critic_weights
            held = held_critics.hold(state.critic, state.target_critic, state.critic_opt,
                                     structure, critic.dtype, in_dtype)  # fmt: skip
            state = state.replace(held=held, critic=None, target_critic=None, critic_opt=None)
        return state.replace(target_nets=build_targets(state))

    def release(state: LearnerState) -> LearnerState:
        state = state.replace(target_nets=None)
        if state.held is None:
            return state
        critic_params, target, opt = held_critics.release(state.held, critics_shape, structure)
        return state.replace(critic=critic_params, target_critic=target, critic_opt=opt, held=None)

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

    def q_select(state: LearnerState, obs: jax.Array, action: jax.Array) -> jax.Array:
        if state.held is not None:
            return jnp.min(held_critics.q_values(state.held, obs, action, per_critic), axis=0)
        q = apply_critics(critic_fp32.apply, state.critic, obs, action, per_critic)
        return jnp.min(q, axis=0)

    def critic_gradient(state: LearnerState, loss_fn: Callable):
        """(loss_fn's value and aux, θ's gradient, θ, its Adam state, the gradient's norm):
        differentiated with respect to what the critics' GEMMs read, then pulled back to θ
        through the build or, held, onto the held matrices (``held_critics.gradient``)."""
        if state.held is not None:
            value, d_nets = jax.value_and_grad(loss_fn, has_aux=True)(state.held.online_nets())
            grads = held_critics.gradient(d_nets, structure)
            norm = held_critics.global_norm(grads, structure)
            return value, grads, state.held.online, state.held.opt, norm
        nets, pullback = jax.vjp(jax.vmap(critic_net.build), state.critic)
        value, d_nets = jax.value_and_grad(loss_fn, has_aux=True)(nets)
        (grads,) = pullback(d_nets)
        return value, grads, state.critic, state.critic_opt, optax.global_norm(grads)

    def critic_step(
        state: LearnerState, batch: Transition, key: jax.Array, hp: HParams
    ) -> tuple[LearnerState, Metrics]:
        built = state.target_nets is not None  # static: the state's structure
        target_actor, target_critics = state.target_nets if built else build_targets(state)
        if state.held is not None:
            target_critics = state.held.target_nets()
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

        def loss_fn(nets):
            # [n_critics, n]
            q = apply_critics(critic_net.forward, nets, batch.obs, batch.action, per_critic)
            losses = critic_losses(q, targets)
            return jnp.sum(losses), (losses, q)

        (_, (losses, q)), grads, params, opt, norm = critic_gradient(state, loss_fn)
        updates, opt = adam(hp.lr_critic).update(grads, opt, params)
        params = optimizer.apply_updates(params, updates, state.critic_updates)
        if state.held is None:
            new_state = state.replace(critic=params, critic_opt=opt)
        else:  # in bf16 the copy the GEMMs read is written in Adam's pass
            copy = held_critics.copies(params, critic.dtype)
            new_state = state.replace(held=state.held._replace(online=params, opt=opt,
                                                               online_copy=copy))  # fmt: skip
        metrics = {
            "loss/critic": jnp.mean(losses),
            "q/mean": jnp.mean(q),
            "q/target": jnp.mean(targets),
            "q/clipped": clipped,
            "grad_norm/critic": norm,
        }
        return new_state.replace(critic_updates=state.critic_updates + 1), metrics

    def actor_step(
        state: LearnerState, batch: Transition, hp: HParams, episode: jax.Array | int = 0
    ) -> tuple[LearnerState, Metrics]:
        if state.held is None:
            q1_nets = critic_net.build(_first_critic(state.critic))
        else:
            q1_nets = _first_critic(state.held.online_nets())

        def q1(obs, action):
            return critic_net.forward(q1_nets, obs, action)

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
            actor_updates=state.actor_updates + 1,
        )
        if state.held is None:
            new_state = new_state.replace(
                target_critic=soft_update(state.target_critic, state.critic, hp.tau)
            )
        else:  # the structure's entries stay exact: τ·1 + (1 - τ)·1 rounds to 1 (and so 0, ±)
            target = held_critics.soft_update(state.held.target, state.held.online, hp.tau,
                                              state.actor_updates)  # fmt: skip
            copy = held_critics.copies(target, critic.dtype)
            new_state = new_state.replace(held=state.held._replace(target=target,
                                                                   target_copy=copy))  # fmt: skip
        if state.target_nets is not None:  # the soft update changed them
            new_state = new_state.replace(target_nets=build_targets(new_state))
        metrics = {
            "loss/actor": loss,
            "advisor/replaced": jnp.mean(replaced.astype(jnp.float32)),
            "grad_norm/actor": optax.global_norm(grads),
            **diagnostics,
        }
        return new_state, metrics

    def sample(replay: ReplayState, key: jax.Array) -> Transition:
        with jax.named_scope("replay_sample"):  # scopes: labels for profiles, nothing else
            return replay_sample(replay, key, cfg.batch_size)

    def critic_on(state, batch, critic_key, hp):
        with jax.named_scope("critic_step"):
            return critic_step(state, batch, critic_key, hp)

    def skip_actor(state, batch, hp, episode):
        return state, nan_like(jax.eval_shape(actor_step, state, batch, hp, episode)[1])

    def finish(state, critic_metrics, actor_metrics, took_actor):
        nonfinite = ~all_finite(critic_metrics) | (took_actor & ~all_finite(actor_metrics))
        return state, {**critic_metrics, **actor_metrics}, nonfinite

    def update(
        state: LearnerState,
        batch: Transition,
        critic_key: jax.Array,
        hp: HParams,
        update_index: jax.Array | int,
        episode: jax.Array | int = 0,
    ) -> tuple[LearnerState, Metrics, jax.Array]:
        """One update (Alg. 2 steps 7-15, Alg. A3 steps 10-22) on B: critic, delayed actor.

        Args:
          batch: B, drawn by ``sample``; critic_key: TD3's target smoothing noise.
          update_index: global index of this update; the actor step runs when
            ``update_index % d == 0`` (``lax.cond``). Pass it *unbatched* under ``vmap``:
            the test then stays a scalar and the cond really skips the actor step instead
            of computing and selecting it.
          episode: episodes the agent has completed (the N_P gate of ``actor_step``).

        Returns:
          The new state; the critic and actor metrics (the actor's NaN on updates that
          skip it); and whether any loss computed in this update was non-finite.
        """
        state, critic_metrics = critic_on(state, batch, critic_key, hp)
        with jax.named_scope("actor_step"):
            took_actor = update_index % cfg.delay == 0
            state, actor_metrics = jax.lax.cond(
                took_actor,
                lambda s: actor_step(s, batch, hp, episode),
                lambda s: skip_actor(s, batch, hp, episode),
                state,
            )
        return finish(state, critic_metrics, actor_metrics, took_actor)

    def update_with_actor(state, batch, critic_key, hp, episode=0):
        """``update`` at an index where the delay takes the actor step, compiled with no
        conditional (a caller that knows the schedule statically: the steady program of
        ``training.train``, which a GPU runs as one graph of overlapping kernels)."""
        state, critic_metrics = critic_on(state, batch, critic_key, hp)
        with jax.named_scope("actor_step"):
            state, actor_metrics = actor_step(state, batch, hp, episode)
        return finish(state, critic_metrics, actor_metrics, jnp.ones((), bool))

    def update_critic_only(state, batch, critic_key, hp, episode=0):
        """``update`` at an index where the delay skips the actor step, with no conditional
        (as ``update_with_actor``); the actor metrics are NaN."""
        state, critic_metrics = critic_on(state, batch, critic_key, hp)
        with jax.named_scope("actor_step"):
            state, actor_metrics = skip_actor(state, batch, hp, episode)
        return finish(state, critic_metrics, actor_metrics, jnp.zeros((), bool))

    return Learner(
        init=init,
        q_select=q_select,
        sample=sample,
        critic_step=critic_step,
        actor_step=actor_step,
        update=update,
        update_with_actor=update_with_actor,
        update_critic_only=update_critic_only,
        hold=hold,
        release=release,
    )
