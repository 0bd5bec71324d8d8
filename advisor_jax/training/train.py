"""The RL core: one agent's environment step and updates (Alg. 1 / A2, Alg. 2 / A3), and the
chunk that scans them.

One agent's step, all inside ``lax.scan`` (the caller vmaps over agents)::

    step(state, hp, t):                                      # one environment step
        active = N < N_total and not diverged
        collect:  a_act = π(s);  a_adv = advisor(s)          # Alg. 1 steps 9-10 (any
                                                             # advisor, its quality knobs)
                  if AfD:  ε = Eq. (1) with Q = critic (min of twins)     # step 11 / A2 11-13
                           a = a_adv with probability ε, else a_act       # step 12
                  a = clip(a + Ornstein–Uhlenbeck noise, action box)      # step 13
                  s', r, terminal = env.step(s, a)     (auto-reset)       # steps 14-15
        learn:    once the buffer holds `warmup` transitions, `updates_per_step` times:
                      B = replay.sample(n)    (the buffer before this step's transition)
                      Learner.update: critic_step(B)                           # Alg. 2 6-8
                      every d-th update: actor_step(B) + soft targets          # Alg. 2 9-15
        store:    replay.add(s, a, a_adv, r, s', terminal)   (after learn)   # Alg. 1 step 16
        finish:   a non-finite loss freezes the agent; actor snapshots
    chunk(state, hp, first_step) = scan(step, t = first_step .. + chunk_steps - 1)

Collect and learn both read the state the step starts from (``training/draws.py``).
``make_core`` builds these pieces; ``make_train`` scans them into the paper's agents'
program; a baseline's (LfD, MCP+MF) is built from them in ``training/prior/``;
``training/program.py`` picks the program.

Episode budget. An agent is *active* until it has completed N_total episodes (or its losses
went non-finite). An inactive agent keeps stepping (one lane of a vmapped program) but learns
nothing: the hyperparameters declared ``freezes`` (learning rates, τ) are multiplied by 0, so
its parameters stay exactly as they were, and its episode log ignores further episodes. So
one vmapped run of many agents equals the same agents run one by one.

Static schedule. The warm-up test and the TD3 delay ``update % d == 0`` depend only on the
global step index, which the caller passes *unbatched* (``first_step``) and the scan derives
from ``arange``: under ``vmap`` they stay scalars, so ``lax.cond`` really skips the actor
update on 3 of 4 steps instead of computing it and selecting.

Steady program (``make_train``'s ``steady``): a second program of the same steps with no
conditional inside, blocks of d steps written out in a row, the first with the actor update
(``Learner.update_with_actor``), the others without (``update_critic_only``), all past
warm-up. One ``lax.cond`` per chunk picks it when the whole chunk is past warm-up and starts a
delay period (``steady_at``). Both run the same operations on the same random streams
(tests/training/test_steady_program.py, experiments/steady_parity.py). Without conditionals
a GPU runs the whole loop as one graph of overlapping kernels (``compiler.compiler_options``).
"""

from __future__ import annotations

import functools
import math
from collections.abc import Callable
from typing import Any, NamedTuple

import jax
import jax.numpy as jnp

import envs
from advisor_jax.agent.advisor_quality import advisor_key, make_acting, memory_init, restart
from advisor_jax.agent.config import TrainConfig
from advisor_jax.agent.hparams import HParams
from advisor_jax.agent.learner import Learner, make_learner, nan_like
from advisor_jax.agent.networks import MODULES, Layout, make_actor
from advisor_jax.agent.noise import ou_init, ou_reset, ou_step
from advisor_jax.agent.replay_buffer import Transition, replay_init
from advisor_jax.agent.selector import select_action
from advisor_jax.agent.settings import freeze
from advisor_jax.contract import spec
from advisor_jax.training import draws
from advisor_jax.training.advisor_source import resolve_advisor
from advisor_jax.training.state import (
    TrainState,
    empty_log,
    no_snapshots,
    take_snapshots,
    write_episodes,
)
from envs.reward import return_bounds

Metrics = dict[str, jax.Array]


class Core(NamedTuple):
    """The pieces of one agent's step (pure; see the module docstring), for the programs
    that scan them: ``make_train`` and a baseline's (``training/prior/``)."""

    env: Any  # envs.NavEnv
    learner: Learner
    actor: Any  # networks.Actor, fp32: the acting policy
    advisor: Any  # agent.advisors.Advisor: the run's advisor (``TrainConfig.advisor``)
    init: Callable[[jax.Array], TrainState]
    act: Callable[..., tuple[jax.Array, jax.Array, Any]]
    """(state, obs [E, 20], hp) -> (π(s), a_adv, advisor memory): a_adv from the advisor under
    the agent's quality knobs (``hp.quality``), drawing on a key of its own."""
    step_envs: Callable[..., tuple[Any, Transition]]
    """(state, obs, chosen [E, 2], noise [E, 2], label [E, 2]) -> (env state, transition):
    the executed action clip(chosen + noise), one env step, the replay row."""
    record: Callable[..., TrainState]
    """(state, key, env_state, noise_state, replay, fired [E], done [E], active, advisor
    memory) -> state: the step's env, noise, buffer, advisor memory and key kept, and its
    finished episodes logged."""
    draw: Callable[[Any, jax.Array], draws.Draws]
    """(replay, key) -> the step's minibatches from ``replay`` (``training/draws.py``)."""
    learn: Callable[..., tuple[TrainState, Metrics, jax.Array]]
    """(state, hp, step index, draws) -> (state, metrics, nonfinite): the updates on ``draws``."""
    learn_past_warmup: Callable[[Callable], Callable]
    """(a ``Learner`` update) -> ``learn`` for steps past warm-up, with no conditional."""
    finish: Callable[..., tuple[TrainState, Metrics]]
    """(state, active, nonfinite, metrics) -> (state, metrics): divergence and snapshots."""
    max_steps: int  # environment steps per env after which every agent is surely done


class PhaseReport(NamedTuple):
    """What a program that plays phases before RL (``training/prior/``) adds to a run's
    outputs: run.json's ``phases``, each episode's phase, extra final parameters."""

    describe: list[dict]
    names: tuple[str, ...]
    episode_phases: Callable[[Any, int], Any]  # (hp, N_total) -> [agents, N_total] int8
    params: Callable[[Any], dict]  # final state -> extra params/ entries


class Trainer(NamedTuple):
    """A population's program for one agent: pure functions, jit and vmap them at the call
    site (``program.population_functions``)."""

    init: Any  # (key) -> state
    chunk: Any  # (state, hp, first_step) -> (state, metrics [chunk_steps])
    max_steps: int  # scan steps after which every agent is surely done
    steady: bool = False  # whether ``chunk`` holds the steady program (module docstring)
    phases: PhaseReport | None = None  # a baseline's phases before RL (``training/prior/``)
    advisor: Any = None  # agent.advisors.Advisor the program consults (run.json's record)


def init_keys(key: jax.Array) -> jax.Array:
    """[3] keys of ``Core.init``: the state's key, the learner's and the envs'. A program
    that adds state of its own derives that state's key from the learner's, leaving the
    core's streams as they were."""
    return jax.random.split(key, 3)


def make_core(cfg: TrainConfig, layout: Layout = MODULES) -> Core:
    """The pieces of one agent type's step (static config); ``layout``: how the learner's
    networks are computed (``program.network_layout``).

    Long: the factory of the step's closures, which share its env, learner and settings;
    each is short."""
    agent = cfg.agent
    env = envs.make_env(cfg.arena, motion=cfg.motion, max_episode_steps=cfg.max_episode_steps)
    advisor = resolve_advisor(cfg.advisor, env)  # a user's function checked here
    advise = make_acting(advisor.apply, advisor.params)
    bounds = functools.partial(return_bounds, env.config)
    learner = make_learner(agent, bounds, layout)
    actor = make_actor(agent.actor_hidden)
    n_envs, n_total = cfg.envs_per_agent, cfg.episodes
    action_low = jnp.asarray(spec.ACTION_LOW, jnp.float32)
    action_high = jnp.asarray(spec.ACTION_HIGH, jnp.float32)
    snapshot_at = jnp.asarray(cfg.snapshot_episodes, jnp.int32).reshape(-1)  # [K]

    def init(key: jax.Array) -> TrainState:
        key, k_learner, k_env = init_keys(key)
        learner_state = learner.init(k_learner)
        return TrainState(
            learner=learner_state,
            replay=replay_init(agent.buffer_size),
            env=jax.vmap(env.reset)(jax.random.split(k_env, n_envs)),
            noise=ou_init((n_envs, spec.ACTION_SIZE)),
            advisor=memory_init(n_envs),
            actor_steps=jnp.zeros(n_envs, jnp.int32),
            episodes=jnp.zeros((), jnp.int32),
            env_steps=jnp.zeros((), jnp.int32),
            diverged=jnp.zeros((), bool),
            log=empty_log(n_total),
            snapshots=no_snapshots(learner_state.actor, snapshot_at),
            key=key,
        )

    def act(state: TrainState, obs: jax.Array, hp: HParams):
        actor_action = actor.apply(state.learner.actor, obs)  # [E, 2]
        # The advisor's key is folded from the step's: every other stream stays as it was.
        advisor_action, memory = advise(hp.quality, state.advisor, obs, advisor_key(state.key))
        return actor_action, advisor_action, memory

    def step_envs(state: TrainState, obs, chosen, noise, label):
        action = jnp.clip(chosen + noise, action_low, action_high)
        env_state = jax.vmap(env.step)(state.env, action)
        transition = Transition(
            obs=obs,
            action=action,
            advisor_action=label,
            reward=env_state.reward,
            next_obs=env_state.terminal_obs,
            terminal=env_state.terminal.astype(jnp.float32),
        )
        return env_state, transition

    def record(state: TrainState, key, env_state, noise_state, replay, fired, done, active, memory):
        actor_steps = state.actor_steps + fired.astype(jnp.int32)
        log = write_episodes(state.log, state.episodes, env_state, actor_steps, done)
        return state.replace(
            replay=replay,
            env=env_state,
            noise=ou_reset(noise_state, done),
            advisor=restart(memory, done),
            actor_steps=jnp.where(done, 0, actor_steps),
            episodes=state.episodes + jnp.sum(done, dtype=jnp.int32),
            env_steps=state.env_steps + n_envs * active.astype(jnp.int32),
            log=log,
            key=key,
        )

    draw = functools.partial(draws.draw_batches, learner, cfg.updates_per_step)

    def run_updates(learner_state, state: TrainState, hp: HParams, step_index, drawn, update):
        """`updates_per_step` calls of ``update`` (a ``Learner`` update) from
        ``learner_state`` on ``drawn``: (learner state, mean metrics, whether any computed
        loss was non-finite)."""

        def one_update(learner_state, xs):
            u, batch, k_critic = xs
            index = step_index * cfg.updates_per_step + u  # unbatched: a static schedule
            learner_state, metrics, bad = update(
                learner_state, batch, k_critic, hp, index, state.episodes
            )
            return learner_state, (metrics, bad)

        xs = (jnp.arange(cfg.updates_per_step), drawn.batches, drawn.critic_keys)
        learner_state, (metrics, bad) = jax.lax.scan(one_update, learner_state, xs)
        return learner_state, jax.tree_util.tree_map(jnp.nanmean, metrics), jnp.any(bad)

    def learn(state: TrainState, hp: HParams, step_index: jax.Array, drawn: draws.Draws):
        """The step's updates (Alg. 2 / A3) on ``drawn`` once their buffer held ``warmup``
        transitions (``lax.cond``s on the unbatched step index, as the actor's delay): the new
        state, the mean metrics (NaN where not computed), whether a computed loss was not finite."""

        def updates(learner_state):
            return run_updates(learner_state, state, hp, step_index, drawn, learner.update)

        def no_updates(learner_state):
            metrics = jax.eval_shape(updates, learner_state)[1]
            return learner_state, nan_like(metrics), jnp.zeros((), bool)

        ready = step_index * n_envs >= agent.warmup  # unbatched: same for all agents
        learner_state, metrics, bad = jax.lax.cond(ready, updates, no_updates, state.learner)
        return state.replace(learner=learner_state, key=drawn.key), metrics, bad

    def learn_past_warmup(update):
        """``learn`` for steps known to be past warm-up, each update ``update`` (called with
        ``Learner.update``'s arguments): no conditional."""

        def learn(state: TrainState, hp: HParams, step_index: jax.Array, drawn: draws.Draws):
            learner_state, metrics, bad = run_updates(
                state.learner, state, hp, step_index, drawn, update
            )
            return state.replace(learner=learner_state, key=drawn.key), metrics, bad

        return learn

    def finish(state: TrainState, active, nonfinite, metrics):
        state = state.replace(diverged=state.diverged | (nonfinite & active))
        state = state.replace(snapshots=take_snapshots(state, snapshot_at))
        return state, {**metrics, "train/active": active, "train/episodes": state.episodes}

    return Core(
        env=env,
        learner=learner,
        actor=actor,
        advisor=advisor,
        init=init,
        act=act,
        step_envs=step_envs,
        record=record,
        draw=draw,
        learn=learn,
        learn_past_warmup=learn_past_warmup,
        finish=finish,
        max_steps=math.ceil(n_total / n_envs) * env.max_episode_steps,
    )


def make_train(
    cfg: TrainConfig,
    steady: bool = False,
    layout: Layout = MODULES,
    hold: bool = True,
    free_store: bool = False,
) -> Trainer:
    """The paper's agents' program (static config): the core's steps scanned into chunks.

    ``steady``: also compile the chunk's steady program (module docstring), where it exists:
    one update per step or no delay, and chunks a whole number of delay periods. ``hold``: a
    chunk holds the learner's built targets and, where its layout says, critics
    (``Learner.hold``). ``free_store``: the steady blocks store with no barrier
    (``draws.store_free``). ``training/program.py`` decides each where it pays.

    Long: the factory of the chunk's closures (collect, step, the two loops), which share
    the core and its settings; each is short."""
    core = make_core(cfg, layout)
    agent, learner = cfg.agent, core.learner
    n_envs, n_total = cfg.envs_per_agent, cfg.episodes
    delay_in_whole_steps = cfg.updates_per_step == 1 or agent.delay == 1
    steady = steady and delay_in_whole_steps and cfg.chunk_steps % agent.delay == 0

    def collect(state: TrainState, hp: HParams, active: jax.Array):
        """Every env's environment step (Alg. 1 / A2 steps 8-15): state, transition (unstored)."""
        key, k_select, k_noise = jax.random.split(state.key, 3)
        obs = state.env.obs  # [E, 20]
        actor_action, adv_action, memory = core.act(state, obs, hp)
        if agent.advisor_data:
            select = jax.vmap(select_action, in_axes=(0, 0, 0, 0, 0, None, None))
            keys = jax.random.split(k_select, n_envs)
            q = (learner.q_select(state.learner, obs, a) for a in (actor_action, adv_action))  # [E]
            chosen, used_advisor = select(keys, actor_action, adv_action, *q, state.episodes, hp)
        else:
            chosen, used_advisor = actor_action, jnp.zeros(n_envs, bool)
        noise_state, noise = ou_step(state.noise, k_noise, hp.ou_theta, hp.ou_sigma)
        env_state, transition = core.step_envs(state, obs, chosen, noise, adv_action)
        fired = ~used_advisor
        done = env_state.done
        state = core.record(
            state, key, env_state, noise_state, state.replay, fired, done, active, memory
        )
        return state, transition

    def step(state: TrainState, hp, step_index, learn=core.learn, pending=None):
        """One environment step and its updates (the outline above): state, metrics and,
        given the previous step's ``pending`` transition (stored first), this step's; without,
        it is stored once the update is computed (``training/draws.py`` says why)."""
        if pending is not None:
            state = state.replace(replay=draws.store_pending(state.replay, pending))
        active = (state.episodes < n_total) & ~state.diverged
        # Named scopes label ops for profiles (experiments/profile_train.py), nothing else.
        with jax.named_scope("collect"):
            collected, transition = collect(state, hp, active)
        with jax.named_scope("learn"):  # on the buffer before this step's transition
            drawn = core.draw(state.replay, collected.key)
            learned, metrics, nonfinite = learn(state, freeze(hp, active), step_index, drawn)
        fed, replay = (learned.learner, metrics, nonfinite), state.replay
        if pending is None:
            store = draws.store_free if free_store else draws.store_after
            fed, replay = store(replay, transition, fed)
        else:
            pending = draws.Pending(transition, jnp.ones(n_envs, bool))
        learner_state, metrics, nonfinite = fed
        state = collected.replace(learner=learner_state, key=learned.key, replay=replay)
        state, metrics = core.finish(state, active, nonfinite, metrics)
        return state, metrics, pending

    def general_chunk(state: TrainState, hp: HParams, first_step: jax.Array):
        steps = first_step + jnp.arange(cfg.chunk_steps, dtype=jnp.int32)
        return draws.scan_pending(lambda s, i, p: step(s, hp, i, pending=p), state, steps, n_envs)

    # The steady program's two updates, called with the general update's arguments.
    with_actor, critic_only = (
        core.learn_past_warmup(lambda s, b, kc, hp, index, n, f=f: f(s, b, kc, hp, n))
        for f in (learner.update_with_actor, learner.update_critic_only)
    )

    def steady_chunk(state: TrainState, hp: HParams, first_step: jax.Array):
        """The same steps without a conditional: blocks of d steps written out one after the
        other (not a nested scan, which ran slower), the first with the actor update, all
        past warm-up (valid when ``steady_at(first_step)``)."""

        def block(state: TrainState, first: jax.Array):
            metrics = []
            for j in range(agent.delay):
                state, m, _ = step(state, hp, first + j, with_actor if j == 0 else critic_only)
                metrics.append(m)
            return state, jax.tree.map(lambda *ms: jnp.stack(ms), *metrics)

        firsts = first_step + jnp.arange(0, cfg.chunk_steps, agent.delay, dtype=jnp.int32)
        state, metrics = jax.lax.scan(block, state, firsts)
        return state, jax.tree.map(lambda x: x.reshape(-1, *x.shape[2:]), metrics)

    def chunk(state: TrainState, hp: HParams, first_step: jax.Array):
        """`chunk_steps` environment steps; `first_step` is the global index of the first.
        The state it takes and returns holds nothing (``Learner.release``): flax trees."""
        if hold:
            state = state.replace(learner=learner.hold(state.learner))
        if not steady:
            state, metrics = general_chunk(state, hp, first_step)
        else:  # one conditional per chunk (its predicate is unbatched), none in the steady loop
            state, metrics = jax.lax.cond(
                steady_at(first_step, n_envs, agent.warmup, agent.delay),
                lambda s: steady_chunk(s, hp, first_step),
                lambda s: general_chunk(s, hp, first_step),
                state,
            )
        return state.replace(learner=learner.release(state.learner)), metrics

    return Trainer(
        init=core.init, chunk=chunk, max_steps=core.max_steps, steady=steady, advisor=core.advisor
    )


def steady_at(first_step, n_envs: int, warmup: int, delay: int):
    """Whether a chunk whose first step is global step ``first_step`` may run the steady
    program: each of its steps finds ``warmup`` transitions of ``n_envs`` envs stored (its
    own are stored after its update) and it starts a delay period, so its actor updates (every
    ``delay``-th, counted from step 0) fall on the heads of its blocks."""
    return (first_step * n_envs >= warmup) & (first_step % delay == 0)
