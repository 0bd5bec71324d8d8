"""LfD (Pfeiffer et al., RA-L 2018) as phases of the training scan (docs/baselines.md, "LfD").

Pfeiffer et al. pre-train a navigation policy by imitating expert demonstrations, then
train it by RL starting from the imitated actor, with a fresh value function. Ours, with the
advisor as the expert and DDPG (or TD3) as the RL learner::

    demo      D = demo_episodes episodes: a = clip(a_adv + OU noise)     (counted in N_total)
              replay.add(s, a, a_adv, r, s', terminal)   a_adv: the clean label
    imitate   bc_steps times: B ~ replay (= the demonstrations only)
              φ ← Adam(bc_lr) step of (1/n) Σ ‖π_φ(s) − a_adv‖²            (agent/imitation.py)
              φ^T ← φ (the target actor is the imitated actor when imitation ends)
    warmup    critic_warmup times: B ~ replay (batch n);  critic_step(B);  θ^T ← τθ + (1−τ)θ^T
              the actor and its Adam state untouched (fresh for RL)
    rl        the DDPG / TD3 loop of ``make_train`` for the remaining N_total − D episodes,
              the demonstrations staying in the replay buffer

Why (docs/baselines.md, "Rules shared by both baselines"): noisy execution gives the critic
action variety while clean labels do not teach the noise; Pfeiffer loads only the actor and
CPO's trust region protects it, which DDPG lacks, so the fresh critic first learns the
imitated policy's values (with τ = 0.1, γ = 0.9, 1,000 updates cover its ≈10-step horizon;
the target critic follows by the soft update so that it does). ``critic_warmup = 0`` is the
sources' literal reading.
"""

from __future__ import annotations

import jax
import jax.numpy as jnp

from advisor_jax.agent.config import TrainConfig
from advisor_jax.agent.imitation import imitation_init, imitation_step
from advisor_jax.agent.replay_buffer import replay_sample
from advisor_jax.agent.update_rules import soft_update
from advisor_jax.training.prior.phases import Control, Phase, Schedule


def lfd_schedule(cfg: TrainConfig, learner, actor, env=None) -> Schedule:
    """demo (advisor, D episodes) → imitate (bc_steps) → warmup (critic_warmup) → RL."""
    settings = cfg.agent.baseline

    def demonstrate(state, obs, actor_action, advisor_action, key, hp, extra) -> Control:
        # The advisor acts; OU noise is added by the trainer; a_adv is stored as the label.
        return Control(advisor_action, jnp.zeros(obs.shape[0], bool), 1.0)

    def imitate(state, hp):
        key, k_sample = jax.random.split(state.key)
        # Nothing has been stored since the demonstrations: the buffer holds them alone.
        batch = replay_sample(state.replay, k_sample, settings.bc_batch)
        params, opt, metrics = imitation_step(
            actor, state.learner.actor, state.prior.data, batch.obs, batch.advisor_action,
            hp.prior.bc_lr,
        )  # fmt: skip
        learner_state = state.learner.replace(actor=params, target_actor=params)
        bad = ~jnp.isfinite(metrics["bc/loss"])
        return state.replace(learner=learner_state, prior=state.prior.replace(data=opt),
                             key=key), metrics, bad  # fmt: skip

    phases = [
        Phase("demo", episodes="demo_episodes", act=demonstrate),
        Phase("imitate", steps=settings.bc_steps, update=imitate, gated=True),
    ]
    if settings.critic_warmup:
        warmup = warm_critic(cfg, learner)
        phases.append(Phase("warmup", steps=settings.critic_warmup, update=warmup, gated=True))
    return Schedule(phases=tuple(phases), init=lambda learner_state, key: imitation_init(
        learner_state.actor))  # fmt: skip


def warm_critic(cfg: TrainConfig, learner):
    """The critic warm-up update (one step; shared with MCP+MF): ``learner.critic_step`` on a
    batch of n from the replay buffer, then the soft update of the target critic; the actor,
    the target actor and the actor's Adam state are untouched."""

    def update(state, hp):
        key, k_sample, k_critic = jax.random.split(state.key, 3)
        batch = replay_sample(state.replay, k_sample, cfg.agent.batch_size)
        learner_state, m = learner.critic_step(state.learner, batch, k_critic, hp.rl)
        learner_state = learner_state.replace(
            target_critic=soft_update(learner_state.target_critic, learner_state.critic, hp.rl.tau)
        )
        metrics = {"critic/warmup_loss": m["loss/critic"], "critic/warmup_q": m["q/mean"]}
        bad = ~(jnp.isfinite(m["loss/critic"]) & jnp.isfinite(m["grad_norm/critic"]))
        return state.replace(learner=learner_state, key=key), metrics, bad

    return update
