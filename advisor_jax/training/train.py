"""The jitted training core: data collection (Alg. 1 / A2) and updates (Alg. 2 / A3).

One agent's step, all inside ``lax.scan`` (the caller vmaps over agents)::

    a_act = π(s);  a_adv = advisor(s)                        # Alg. 1 steps 9-10
    if AfD:  ε = Eq. (1) with Q = critic (min of twins)       # Alg. 1 step 11 / A2 11-13
             a = a_adv with probability ε, else a_act        # step 12
    a = clip(a + Ornstein–Uhlenbeck noise, action box)       # step 13
    s', r, terminal = env.step(s, a)     (auto-reset)        # steps 14-15
    replay.add(s, a, a_adv, r, s', terminal)                 # step 16
    once the buffer holds `warmup` transitions, `updates_per_step` times:
        B = replay.sample(n)
        critic_step(B)                                       # Alg. 2 steps 6-8 / A3 9-14
        every d-th update: actor_step(B) + soft targets      # Alg. 2 steps 9-15 / A3 15-22

Episode budget. An agent is *active* until it has completed N_total episodes (or its losses
went non-finite). An inactive agent keeps stepping (it is one lane of a vmapped program) but
learns nothing: its learning rates and τ are multiplied by 0, so its parameters stay exactly
as they were, and its episode log ignores further episodes. This makes one vmapped run of
many agents equal to the same agents run one by one.

Baselines (LfD, MCP+MF; docs/baselines.md). A baseline agent's prior-knowledge phases
(demonstration, random or MPC episodes, model and actor fits, critic warm-up) run in the
same scan, chosen per step from its own counters by ``training/phases.py``; a paper agent's
program is unchanged (``prior`` None). The baselines' heavy bodies (offline updates, the MPC
plan, and the RL update ``learn`` below) run under ``lax.cond`` on the population's
unbatched ``gate`` (``chunk``'s fourth argument): on only while some agent may be in a
phase that uses them during the chunk (``phases.chunk_gate``).

Static schedule. The warm-up test and the TD3 delay ``update % d == 0`` depend only on the
global step index, which the caller passes *unbatched* (``first_step``) and the scan derives
from ``arange``: under ``vmap`` they stay scalars, so ``lax.cond`` really skips the actor
update on 3 of 4 steps instead of computing it and selecting.

Steady program (small populations on GPUs, ``host_loop.population_functions``). The chunk
also holds a second program of the same steps with no conditional inside: blocks of d steps
written out in a row, whose first step takes the actor update and whose others do not, all
past warm-up. One ``lax.cond`` per chunk picks it when the whole chunk is past warm-up and
starts a delay period (``steady_at``: every chunk after the first few when ``chunk_steps``
is a multiple of d), the general program otherwise. Both run the same operations on the same
random streams (tests/train/test_steady_program.py, experiments/steady_parity.py). Without
conditionals the whole loop runs as one CUDA graph whose independent kernels overlap
(``agent.compiler_options``), which a 1-agent step, a chain of ~240 small kernels, needs
(``results/bench_train_steady/``).
"""

from __future__ import annotations

import functools
import math
from typing import Any, NamedTuple

import jax
import jax.numpy as jnp
from flax import struct

import envs
from advisor_jax.agent.advisor import advisor_action, arena_advisor
from advisor_jax.agent.config import HParams, TrainConfig
from advisor_jax.agent.learner import LearnerState, make_learner, nan_like
from advisor_jax.agent.networks import make_actor
from advisor_jax.agent.noise import OUState, ou_init, ou_reset, ou_step
from advisor_jax.agent.replay_buffer import (
    ReplayState,
    Transition,
    replay_add,
    replay_init,
)
from advisor_jax.agent.selector import select_action
from advisor_jax.contract import spec
from advisor_jax.training import phases
from envs.reward import return_bounds


@struct.dataclass
class EpisodeLog:
    """Per-episode metrics of one agent, written at the index of each finished episode."""

    outcome: (
        jax.Array
    )  # [N_total] int32: 0 = not played (yet), else envs.GOAL, COLLISION or TIMEOUT
    length: jax.Array  # [N_total] int32 steps
    episode_return: jax.Array  # [N_total] f32
    collision_speed: jax.Array  # [N_total] f32 m/s, NaN unless the episode was a collision
    actor_steps: jax.Array  # [N_total] int32 steps that executed the actor's action


@struct.dataclass
class ActorSnapshots:
    """One agent's actor as it was on completing each of ``TrainConfig.snapshot_episodes``
    (leading axis [K]): taken at the end of the step whose episode reached the count, after
    that step's update, which is where a run of that many episodes stops."""

    actor: Any  # actor params, leading axis [K]
    taken: jax.Array  # [K] bool: the agent has completed that many episodes
    diverged: jax.Array  # [K] bool: its losses had gone non-finite by then (not evaluated)


@struct.dataclass
class TrainState:
    """Everything one agent carries through the scan."""

    learner: LearnerState
    replay: ReplayState
    env: Any  # envs NavState, leading axis [E]
    noise: OUState  # [E, 2]
    actor_steps: jax.Array  # [E] int32, actor-fired steps of the running episodes
    episodes: jax.Array  # () int32, completed episodes N (Eq. 1)
    env_steps: jax.Array  # () int32, environment steps taken while active (all envs)
    diverged: jax.Array  # () bool, a loss went non-finite: the agent is frozen
    log: EpisodeLog
    key: jax.Array
    prior: Any = None  # phases.PhaseState of a baseline agent; None for the paper's agents
    snapshots: ActorSnapshots | None = None  # None unless TrainConfig.snapshot_episodes


class Trainer(NamedTuple):
    """Pure functions of one agent; jit and vmap them at the call site."""

    init: Any  # (key) -> TrainState
    chunk: Any  # (state, hp, first_step) -> (state, metrics [chunk_steps])
    max_steps: int  # environment steps per env after which every agent is surely done
    schedule: phases.Schedule | None = None  # a baseline's phases before RL (None: none)
    steady: bool = False  # whether ``chunk`` holds the steady program (module docstring)


def make_train(cfg: TrainConfig, steady: bool = False) -> Trainer:
    """Builds the training functions of one agent type (static config).

    ``steady``: also compile the chunk's steady program, chosen per chunk (see "Steady
    program" above; ``host_loop.population_functions`` decides where it pays). It is only
    built where it exists: a paper agent (no baseline schedule) with one update per step or
    no delay, and chunks a whole number of delay periods long."""
    agent = cfg.agent
    env = envs.make_env(cfg.arena, motion=cfg.motion, max_episode_steps=cfg.max_episode_steps)
    advisor = arena_advisor(env)
    learner = make_learner(agent, functools.partial(return_bounds, env.config))
    actor = make_actor(agent.actor_hidden)
    n_envs, n_total = cfg.envs_per_agent, cfg.episodes
    action_low = jnp.asarray(spec.ACTION_LOW, jnp.float32)
    action_high = jnp.asarray(spec.ACTION_HIGH, jnp.float32)
    collision = envs.COLLISION
    schedule = phases.make_schedule(cfg, learner, actor, env)  # None for the paper's agents
    gated = schedule is not None and schedule.gated
    steady = (
        steady
        and schedule is None
        and (cfg.updates_per_step == 1 or agent.delay == 1)
        and cfg.chunk_steps % agent.delay == 0
    )
    snapshot_at = jnp.asarray(cfg.snapshot_episodes, jnp.int32) if cfg.snapshot_episodes else None

    def init(key: jax.Array) -> TrainState:
        key, k_learner, k_env = jax.random.split(key, 3)
        learner_state = learner.init(k_learner)
        prior = None  # a baseline's phase state; its key leaves the others' streams as they were
        if schedule is not None:
            prior = phases.init_state(schedule, learner_state, jax.random.fold_in(k_learner, 1))
        return TrainState(
            learner=learner_state,
            replay=replay_init(agent.buffer_size),
            env=jax.vmap(env.reset)(jax.random.split(k_env, n_envs)),
            noise=ou_init((n_envs, spec.ACTION_SIZE)),
            actor_steps=jnp.zeros(n_envs, jnp.int32),
            episodes=jnp.zeros((), jnp.int32),
            env_steps=jnp.zeros((), jnp.int32),
            diverged=jnp.zeros((), bool),
            log=EpisodeLog(
                outcome=jnp.zeros(n_total, jnp.int32),
                length=jnp.zeros(n_total, jnp.int32),
                episode_return=jnp.zeros(n_total, jnp.float32),
                collision_speed=jnp.full(n_total, jnp.nan, jnp.float32),
                actor_steps=jnp.zeros(n_total, jnp.int32),
            ),
            key=key,
            prior=prior,
            snapshots=None
            if snapshot_at is None
            else _no_snapshots(learner_state.actor, snapshot_at),
        )

    def collect(
        state: TrainState, hp: HParams, active: jax.Array, phase=None, gate=None
    ) -> TrainState:
        """One environment step of every env of the agent (Alg. 1 / A2, steps 8-16).

        A baseline agent (``phase`` given) executes its phase's controller instead, and holds
        the environment in an offline phase (nothing stored, logged or counted)."""
        if schedule is None:
            key, k_select, k_noise = jax.random.split(state.key, 3)
        else:
            key, k_select, k_noise, k_phase = jax.random.split(state.key, 4)
        obs = state.env.obs  # [E, 20]
        actor_action = actor.apply(state.learner.actor, obs)  # [E, 2]
        adv_action = jax.vmap(advisor_action, in_axes=(0, None))(obs, advisor)
        if agent.advisor_data:
            q_actor = learner.q_select(state.learner.critic, obs, actor_action)  # [E]
            q_advisor = learner.q_select(state.learner.critic, obs, adv_action)
            chosen, used_advisor = jax.vmap(select_action, in_axes=(0, 0, 0, 0, 0, None, None))(
                jax.random.split(k_select, n_envs),
                actor_action,
                adv_action,
                q_actor,
                q_advisor,
                state.episodes,
                hp,
            )
        else:
            chosen, used_advisor = actor_action, jnp.zeros(n_envs, bool)
        noise_state, noise = ou_step(state.noise, k_noise, hp.ou_theta, hp.ou_sigma)
        if schedule is not None:
            control, acting = phases.control(
                schedule, phase, state, obs, actor_action, adv_action, k_phase, hp, gate
            )
            chosen, used_advisor = control.action, ~control.actor_fired
            noise = noise * control.noise
            adv_action = control.label  # the stored label: a_adv unless the phase has its own
        action = jnp.clip(chosen + noise, action_low, action_high)
        env_state = jax.vmap(env.step)(state.env, action)

        transition = Transition(
            obs=obs,
            action=action,
            advisor_action=adv_action,
            reward=env_state.reward,
            next_obs=env_state.terminal_obs,
            terminal=env_state.terminal.astype(jnp.float32),
        )
        done = env_state.done  # [E]
        fired = ~used_advisor
        if schedule is None:
            replay = replay_add(state.replay, transition)
        else:  # an offline phase: the env, its noise and its episode stay as they were
            held = lambda new, old: jnp.where(acting, new, old)  # noqa: E731
            env_state = jax.tree.map(held, env_state, state.env)
            noise_state = jax.tree.map(held, noise_state, state.noise)
            done, fired = done & acting, fired & acting
            replay = replay_add(state.replay, transition, jnp.broadcast_to(acting, (n_envs,)))
            active = active & acting
        actor_steps = state.actor_steps + fired.astype(jnp.int32)
        log = _write_episodes(state.log, state.episodes, env_state, actor_steps, collision, done)
        return state.replace(
            replay=replay,
            env=env_state,
            noise=ou_reset(noise_state, done),
            actor_steps=jnp.where(done, 0, actor_steps),
            episodes=state.episodes + jnp.sum(done, dtype=jnp.int32),
            env_steps=state.env_steps + n_envs * active.astype(jnp.int32),
            log=log,
            key=key,
        )

    def learn(state: TrainState, hp: HParams, step_index: jax.Array, actor: bool | None = None):
        """`updates_per_step` calls of the learner's update step (Alg. 2 / A3).

        ``actor`` None: the warm-up gate and the delayed actor step are decided from
        ``step_index`` (``lax.cond``s). True / False: the caller knows the step is past
        warm-up and whether its updates take the actor step (the steady program below).

        Returns the new state, the mean metrics of the updates (NaN where nothing was
        computed) and whether any computed loss was non-finite.
        """
        key, k_updates = jax.random.split(state.key)

        def one_update(carry, u):
            learner_state, key = carry
            key, k_sample, k_critic = jax.random.split(key, 3)
            index = step_index * cfg.updates_per_step + u  # unbatched: a static schedule
            learner_state, metrics, bad = learner.update(
                learner_state, state.replay, k_sample, k_critic, hp, index, state.episodes, actor
            )
            return (learner_state, key), (metrics, bad)

        def run_updates(learner_state):
            (learner_state, _), (metrics, bad) = jax.lax.scan(
                one_update, (learner_state, k_updates), jnp.arange(cfg.updates_per_step)
            )
            return learner_state, jax.tree_util.tree_map(jnp.nanmean, metrics), jnp.any(bad)

        def no_updates(learner_state):
            metrics = jax.eval_shape(run_updates, learner_state)[1]
            return learner_state, nan_like(metrics), jnp.zeros((), bool)

        if actor is None:
            ready = (step_index + 1) * n_envs >= agent.warmup  # unbatched: same for all agents
            learner_state, metrics, bad = jax.lax.cond(
                ready, run_updates, no_updates, state.learner
            )
        else:
            learner_state, metrics, bad = run_updates(state.learner)
        return state.replace(learner=learner_state, key=key), metrics, bad

    def chunk(state: TrainState, hp: HParams, first_step: jax.Array, gate=None):
        """`chunk_steps` environment steps; `first_step` is the global index of the first.

        ``gate`` (a gated baseline, LfD, MCP+MF): ``phases.chunk_gate`` of the whole
        population, computed outside the vmap (``host_loop.population_functions``); None
        computes it from this agent (exact when it runs alone; under a vmap it is then
        batched and every gated body runs, as in an ungated schedule)."""
        if gated and gate is None:
            gate = phases.population_gate(schedule, state, hp, n_total, cfg.chunk_steps)

        def body(state: TrainState, i, actor: bool | None = None):
            active = (state.episodes < n_total) & ~state.diverged
            frozen_hp = hp.replace(
                lr_actor=hp.lr_actor * active,
                lr_critic=hp.lr_critic * active,
                tau=hp.tau * active,
                bc_lr=hp.bc_lr * active,
                model_lr=hp.model_lr * active,
            )
            # Named scopes label the compiled program's ops for profiles
            # (experiments/profile_train.py); they change nothing else.
            if schedule is None:
                with jax.named_scope("collect"):
                    state = collect(state, hp, active)
                with jax.named_scope("learn"):
                    state, metrics, nonfinite = learn(state, frozen_hp, first_step + i, actor)
            else:  # the phase at the start of the step decides both halves
                phase = phases.phase_index(schedule, state.episodes, state.prior.offline_steps, hp)
                state = collect(state, hp, active, phase, gate)
                state, metrics, nonfinite = phases.learn(
                    schedule, phase, state, frozen_hp, first_step + i, learn, gate
                )
            state = state.replace(diverged=state.diverged | (nonfinite & active))
            if snapshot_at is not None:
                state = state.replace(snapshots=_take_snapshots(state, snapshot_at))
            metrics = {**metrics, "train/active": active, "train/episodes": state.episodes}
            return state, metrics

        steps = jnp.arange(cfg.chunk_steps, dtype=jnp.int32)
        if not steady:
            return jax.lax.scan(body, state, steps)

        def steady_chunk(state: TrainState):
            """The same steps without a conditional: blocks of d steps written out one after
            the other (not a nested scan, which ran slower), the first with the actor update,
            all past warm-up (valid when ``steady_at(first_step)``)."""

            def block(state: TrainState, first: jax.Array):
                metrics = []
                for j in range(agent.delay):
                    state, m = body(state, first + j, actor=j == 0)
                    metrics.append(m)
                return state, jax.tree.map(lambda *ms: jnp.stack(ms), *metrics)

            state, metrics = jax.lax.scan(block, state, steps[:: agent.delay])
            return state, jax.tree.map(lambda x: x.reshape(-1, *x.shape[2:]), metrics)

        def general_chunk(state: TrainState):
            return jax.lax.scan(body, state, steps)

        # One conditional per chunk (its predicate is unbatched), none inside the steady loop.
        steady_now = steady_at(first_step, n_envs, agent.warmup, agent.delay)
        return jax.lax.cond(steady_now, steady_chunk, general_chunk, state)

    max_steps = math.ceil(n_total / n_envs) * env.max_episode_steps
    if schedule is not None:  # offline phases take scan steps without env steps
        max_steps += schedule.offline_steps
    return Trainer(init=init, chunk=chunk, max_steps=max_steps, schedule=schedule, steady=steady)


def steady_at(first_step, n_envs: int, warmup: int, delay: int):
    """Whether a chunk whose first step is global step ``first_step`` may run the steady
    program: every one of its steps is past warm-up (the buffer holds ``warmup``
    transitions of ``n_envs`` envs) and it starts a delay period, so its actor updates
    (every ``delay``-th, counted from step 0) fall on the heads of its blocks."""
    return ((first_step + 1) * n_envs >= warmup) & (first_step % delay == 0)


def _no_snapshots(actor, snapshot_at: jax.Array) -> ActorSnapshots:
    k = snapshot_at.shape[0]
    return ActorSnapshots(
        actor=jax.tree.map(lambda p: jnp.zeros((k, *p.shape), p.dtype), actor),
        taken=jnp.zeros(k, bool),
        diverged=jnp.zeros(k, bool),
    )


def _take_snapshots(state: TrainState, snapshot_at: jax.Array) -> ActorSnapshots:
    """Copies the actor into every snapshot whose episode count was just reached."""
    snaps = state.snapshots
    now = (state.episodes >= snapshot_at) & ~snaps.taken  # [K]

    def keep(stored, current):
        return jnp.where(now.reshape(-1, *([1] * current.ndim)), current[None], stored)

    return ActorSnapshots(
        actor=jax.tree.map(keep, snaps.actor, state.learner.actor),
        taken=snaps.taken | now,
        diverged=jnp.where(now, state.diverged, snaps.diverged),
    )


def _write_episodes(
    log: EpisodeLog, episodes, env_state, actor_steps, collision, done=None
) -> EpisodeLog:
    """Stores the metrics of every env whose episode just ended at its episode index."""
    done = env_state.done if done is None else done  # [E]
    n_total = log.outcome.shape[0]
    slot = episodes + jnp.cumsum(done.astype(jnp.int32)) - 1
    slot = jnp.where(done, slot, n_total)  # out of range: dropped
    speed = jnp.where(env_state.outcome == collision, env_state.collision_speed, jnp.nan)
    return EpisodeLog(
        outcome=log.outcome.at[slot].set(env_state.outcome, mode="drop"),
        length=log.length.at[slot].set(env_state.episode_length, mode="drop"),
        episode_return=log.episode_return.at[slot].set(env_state.episode_return, mode="drop"),
        collision_speed=log.collision_speed.at[slot].set(speed, mode="drop"),
        actor_steps=log.actor_steps.at[slot].set(actor_steps, mode="drop"),
    )
