"""A baseline's program: its prior phases and then RL, scanned from the RL core's pieces.

The core (``training/train.py``) knows nothing of baselines. A baseline agent's step is the
core's, wrapped (``phases.py`` explains the phases and the gate)::

    step(state, hp, t, gate):
        active = N < N_total and not diverged
        phase  = phases.phase_index(N, k)                     # k: offline steps done
        collect: π(s), a_adv (core.act); the phase's controller acts (phases.control);
                 core.step_envs; an offline phase holds the env (nothing stored or counted);
                 core.record
        learn:   phases.learn: nothing (collect phase), the phase's update (offline phase),
                 core.learn (RL) on core.draw: the buffer before this step's transition
        store:   the transition, pending until the next step starts (training/draws.py)
        finish:  core.finish
    chunk(state, hp, first_step, gate) = scan(step, t = first_step ..)

``PriorState`` is the core's ``TrainState`` and the phases' own state. The population's
gate (``phases.chunk_gate``) is computed outside the vmap over agents
(``PriorProgram.population_chunk``), so that the heavy bodies are skipped while no agent can
be in them.
"""

from __future__ import annotations

import dataclasses
from typing import Any, NamedTuple

import jax
import jax.numpy as jnp
from flax import struct

from advisor_jax.agent.config import TrainConfig
from advisor_jax.agent.hparams import BaselineHParams
from advisor_jax.agent.networks import MODULES, Layout
from advisor_jax.agent.noise import ou_step
from advisor_jax.agent.settings import freeze
from advisor_jax.training.draws import Pending, scan_pending, store_pending
from advisor_jax.training.prior import phases
from advisor_jax.training.prior.lfd import lfd_schedule
from advisor_jax.training.prior.mcp import mcp_schedule
from advisor_jax.training.state import TrainState
from advisor_jax.training.train import PhaseReport, Trainer, init_keys, make_core

SCHEDULES = {"lfd": lfd_schedule, "mcp": mcp_schedule}
"""``BaselineConfig.kind`` -> (cfg, learner, actor, env) -> its ``phases.Schedule``."""


@struct.dataclass
class PriorState(TrainState):
    """A baseline agent's state: the core's, and its phases' own (counters, the baseline's
    data)."""

    prior: phases.PhaseState


class PriorProgram(NamedTuple):
    """A baseline's program: its trainer, its schedule, and how a population runs it."""

    trainer: Trainer
    """``chunk(state, hp, first_step, gate=None)``: ``gate`` is ``phases.chunk_gate`` of the
    population; None computes it from this agent alone (exact when it runs alone; under a
    vmap it is then batched and every gated body runs, as in an ungated schedule)."""
    schedule: phases.Schedule
    n_total: int
    chunk_steps: int

    def population_gate(self, state, hp, n_real=None) -> jax.Array:
        """The gate of a stacked population (``n_real``: the first agents are real, the
        rest padding; None: all real)."""
        return phases.population_gate(
            self.schedule, state, hp, self.n_total, self.chunk_steps, n_real
        )

    def population_chunk(self, n_real=None, axis_name=None):
        """(stacked state, hp, first_step) -> chunk of every agent, the gate computed from
        all of them, unbatched (an ungated schedule: none)."""
        vmapped = jax.vmap(self.trainer.chunk, in_axes=(0, 0, None, None), axis_name=axis_name)
        if not self.schedule.gated:
            return lambda state, hp, first_step: vmapped(state, hp, first_step, None)

        def chunk(state, hp, first_step):
            return vmapped(state, hp, first_step, self.population_gate(state, hp, n_real))

        return chunk


def make_prior_program(cfg: TrainConfig, layout: Layout = MODULES) -> PriorProgram:
    """The program of ``cfg``'s baseline agent (``cfg.agent.baseline``)."""
    core = make_core(cfg, layout)
    schedule = SCHEDULES[cfg.agent.baseline.kind](cfg, core.learner, core.actor, core.env)
    n_envs, n_total = cfg.envs_per_agent, cfg.episodes

    def init(key: jax.Array) -> PriorState:
        state = core.init(key)
        # The phases' own key leaves the core's streams as they were.
        data = phases.init_state(schedule, state.learner, jax.random.fold_in(init_keys(key)[1], 1))
        fields = {f.name: getattr(state, f.name) for f in dataclasses.fields(TrainState)}
        return PriorState(**fields, prior=data)

    def collect(state: PriorState, hp, active, phase, gate):
        """One environment step: the phase's controller acts; an offline phase holds the env
        (nothing stored, logged or counted). The state after it, its transition and which
        of its rows to store ([E] bool)."""
        key, _, k_noise, k_phase = jax.random.split(state.key, 4)
        obs = state.env.obs  # [E, 20]
        actor_action, adv_action, memory = core.act(state, obs, hp.rl)
        noise_state, noise = ou_step(state.noise, k_noise, hp.rl.ou_theta, hp.rl.ou_sigma)
        control, acting = phases.control(
            schedule, phase, state, obs, actor_action, adv_action, k_phase, hp, gate
        )
        env_state, transition = core.step_envs(
            state, obs, control.action, noise * control.noise, control.label
        )
        held = lambda new, old: jnp.where(acting, new, old)  # noqa: E731
        env_state = jax.tree.map(held, env_state, state.env)
        noise_state = jax.tree.map(held, noise_state, state.noise)
        memory = jax.tree.map(held, memory, state.advisor)
        done, fired = env_state.done & acting, control.actor_fired & acting
        active = active & acting
        state = core.record(
            state, key, env_state, noise_state, state.replay, fired, done, active, memory
        )
        return state, transition, jnp.broadcast_to(acting, (n_envs,))

    def step(state: PriorState, hp: BaselineHParams, step_index, gate, pending: Pending):
        """(state, the previous step's transition) -> (state, metrics, this step's)."""
        state = state.replace(replay=store_pending(state.replay, pending))
        active = (state.episodes < n_total) & ~state.diverged
        # The phase at the start of the step decides both halves; both read the buffer and
        # N as the step found them.
        phase = phases.phase_index(schedule, state.episodes, state.prior.offline_steps, hp)
        collected, transition, stored = collect(state, hp, active, phase, gate)
        drawn = core.draw(state.replay, collected.key)

        def rl_learn(state: PriorState, hp: BaselineHParams, step_index: jax.Array):
            return core.learn(state, hp.rl, step_index, drawn)

        learning = collected.replace(episodes=state.episodes)
        learned, metrics, nonfinite = phases.learn(
            schedule, phase, learning, freeze(hp, active), step_index, rl_learn, gate
        )
        state = learned.replace(episodes=collected.episodes)
        state, metrics = core.finish(state, active, nonfinite, metrics)
        return state, metrics, Pending(transition, stored)

    def chunk(state: PriorState, hp, first_step: jax.Array, gate=None):
        if schedule.gated and gate is None:
            gate = phases.population_gate(schedule, state, hp, n_total, cfg.chunk_steps)
        steps = first_step + jnp.arange(cfg.chunk_steps, dtype=jnp.int32)
        return scan_pending(lambda s, i, p: step(s, hp, i, gate, p), state, steps, n_envs)

    report = PhaseReport(
        describe=phases.describe(schedule),
        names=schedule.names,
        episode_phases=lambda hp, n: phases.episode_phases(schedule, hp, n),
        params=_extra_params,
    )
    # Offline phases take scan steps without env steps.
    trainer = Trainer(
        init, chunk, core.max_steps + schedule.offline_steps, phases=report, advisor=core.advisor
    )
    return PriorProgram(trainer, schedule, n_total, cfg.chunk_steps)


def _extra_params(state: Any) -> dict:
    """The final parameters a baseline adds to params/: MCP+MF's dynamics model."""
    model = getattr(state.prior.data, "model", None)
    if model is None:
        return {}
    return {"model": model.params, "model_norm": model.norm}
