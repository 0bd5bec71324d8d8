"""MCP + model-free (Nagabandi et al., ICRA 2018) as phases of the training scan
(docs/baselines.md, "MCP + model-free").

Nagabandi et al. fit a neural network dynamics model on random-action data, control the
robot by random-shooting MPC through it while aggregating the MPC's data and refitting,
fit a policy to the MPC's actions (then DAgger), and fine-tune that policy model-free. Ours,
with DDPG (or TD3) as the model-free learner, every episode counted against N_total::

    random      R = random_episodes episodes, a ~ U(action box) i.i.d., no OU noise
    normalise   1 step: the model's normaliser from the random data, frozen from then on;
                label_start = replay.size (rows from here on carry the MPC's label)
    fit_model   model_steps steps: model.fit_step on the whole replay buffer
    mpc_rounds × [
      mpc       M = mpc_episodes episodes: a = MPC(s) (K candidates, horizon H), no noise,
                stored label = a
      fit_model model_steps steps (data aggregated: the same weights refitted on all of it) ]
    fit_actor   bc_steps steps: imitation_step of the actor on rows [label_start, size):
                (s, MPC label); the target actor follows the actor
    dagger_rounds × [
      dagger    dagger_episodes episodes: the actor + OU noise acts, the MPC labels s
                (the model is frozen from the last fit_model on)
      fit_actor bc_steps steps, all labelled rows ]
    warmup      critic_warmup critic-only steps (LfD's, training/lfd.py)
    rl          the DDPG / TD3 loop of ``make_train`` for the rest of N_total

Gating (training/phases.py): the MPC action is the schedule's ``precompute`` (one K × H
random-shooting plan per env per step) used by the mpc and dagger phases, every offline
phase is ``gated``, and so is the RL update; the population's flags switch each off for a
chunk in which no agent can be in a phase that uses it (phases only advance, and a phase
more than a chunk's steps of offline work away is out of reach), so the RL half of a run
pays nothing for the prior phases and the prior phases pay for RL only near its start.
While on, every agent's step computes the body, whatever its own phase.
"""

from __future__ import annotations

from typing import Any

import jax
import jax.numpy as jnp
from flax import struct

from advisor_jax.agent.config import TrainConfig
from advisor_jax.agent.dynamics_model import (
    DynamicsState,
    make_dynamics_model,
    normalizer_from_data,
)
from advisor_jax.agent.imitation import imitation_init, imitation_step
from advisor_jax.agent.mpc import make_mpc_policy
from advisor_jax.contract import spec
from advisor_jax.training.prior.lfd import warm_critic
from advisor_jax.training.prior.phases import Control, Phase, Schedule


@struct.dataclass
class McpData:
    """MCP+MF's per-agent state (``PhaseState.data``; checkpointed with the rest)."""

    model: DynamicsState  # the dynamics model: weights, Adam state, normaliser
    bc_opt: Any  # the actor imitation's own Adam state
    label_start: jax.Array  # () int32: first replay row labelled by the MPC


def mcp_schedule(cfg: TrainConfig, learner, actor, env) -> Schedule:
    """random → normalise → fit_model → rounds of (mpc → fit_model) → fit_actor → rounds of
    (dagger → fit_actor) → warmup → RL."""
    settings = cfg.agent.baseline
    model = make_dynamics_model(settings.model_hidden)
    policy = make_mpc_policy(model, settings.mpc_candidates, settings.mpc_horizon, env.config)
    low = jnp.asarray(spec.ACTION_LOW, jnp.float32)
    high = jnp.asarray(spec.ACTION_HIGH, jnp.float32)

    def init(learner_state, key) -> McpData:
        return McpData(model=model.init(key), bc_opt=imitation_init(learner_state.actor),
                       label_start=jnp.int32(0))  # fmt: skip

    def mpc_actions(state, obs, key, hp):  # [E, 20] -> [E, 2], one plan per env
        ms = state.prior.data.model
        keys = jax.random.split(key, obs.shape[0])
        return jax.vmap(policy, in_axes=(None, None, 0, 0))(ms.params, ms.norm, obs, keys)

    def act_random(state, obs, actor_action, advisor_action, key, hp, extra) -> Control:
        action = jax.random.uniform(key, actor_action.shape, jnp.float32, low, high)
        return Control(action, jnp.zeros(obs.shape[0], bool), 0.0)

    def act_mpc(state, obs, actor_action, advisor_action, key, hp, extra) -> Control:
        return Control(extra, jnp.zeros(obs.shape[0], bool), 0.0, label=extra)

    def act_dagger(state, obs, actor_action, advisor_action, key, hp, extra) -> Control:
        return Control(actor_action, jnp.ones(obs.shape[0], bool), 1.0, label=extra)

    def with_data(state, **changes):
        data = state.prior.data.replace(**changes)
        return state.replace(prior=state.prior.replace(data=data))

    def normalise(state, hp):
        replay = state.replay
        norm = normalizer_from_data(replay.data, replay.size)
        state = with_data(state, model=state.prior.data.model.replace(norm=norm),
                          label_start=replay.size)  # fmt: skip
        bad = ~jnp.all(jnp.stack([jnp.all(jnp.isfinite(x)) for x in jax.tree.leaves(norm)]))
        return state, {}, bad

    def fit_model(state, hp):
        key, k_fit = jax.random.split(state.key)
        replay = state.replay
        ms, loss = model.fit_step(
            state.prior.data.model, replay.data, replay.size, k_fit, hp.prior.model_lr,
            hp.prior.model_noise, settings.model_batch,
        )  # fmt: skip
        return with_data(state.replace(key=key), model=ms), {"model/loss": loss}, ~jnp.isfinite(
            loss)  # fmt: skip

    def fit_actor(state, hp):
        key, k_idx = jax.random.split(state.key)
        data, replay = state.prior.data, state.replay
        labelled = jnp.maximum(replay.size - data.label_start, 1)
        idx = data.label_start + jax.random.randint(k_idx, (settings.bc_batch,), 0, labelled)
        params, opt, metrics = imitation_step(
            actor, state.learner.actor, data.bc_opt, replay.data.obs[idx],
            replay.data.advisor_action[idx], hp.prior.bc_lr,
        )  # fmt: skip
        learner_state = state.learner.replace(actor=params, target_actor=params)
        state = with_data(state.replace(learner=learner_state, key=key), bc_opt=opt)
        return state, metrics, ~jnp.isfinite(metrics["bc/loss"])

    def fit(name, steps, update):
        return Phase(name, steps=steps, update=update, gated=True)

    model_fit = fit("fit_model", settings.model_steps, fit_model)
    actor_fit = fit("fit_actor", settings.bc_steps, fit_actor)
    phases = [
        Phase("random", episodes="random_episodes", act=act_random),
        fit("normalise", 1, normalise),
        model_fit,
    ]
    for _ in range(settings.mpc_rounds):
        phases += [Phase("mpc", episodes="mpc_episodes", act=act_mpc), model_fit]
    phases.append(actor_fit)
    for _ in range(settings.dagger_rounds):
        phases += [Phase("dagger", episodes="dagger_episodes", act=act_dagger), actor_fit]
    if settings.critic_warmup:
        phases.append(fit("warmup", settings.critic_warmup, warm_critic(cfg, learner)))
    uses = tuple(i for i, p in enumerate(phases) if p.name in ("mpc", "dagger"))
    return Schedule(phases=tuple(phases), init=init, precompute=mpc_actions, uses=uses)
