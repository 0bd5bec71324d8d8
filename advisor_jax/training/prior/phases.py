"""The phase hook: a baseline's prior-knowledge phases inside the one training scan.

A baseline agent (docs/baselines.md) plays some phases before ordinary RL: episodes driven
by another controller (LfD: the advisor's demonstrations) and offline updates that touch no
environment (LfD: imitation, critic warm-up). Its ``Schedule`` is a static tuple of
``Phase``s followed by the implicit RL phase. Every phase runs in the baseline's own chunk
scan (``trainer.make_prior_program``, built from the RL core's pieces), RL included, so
there is one compiled program and checkpoint / resume work unchanged; the agent's phase at
each scan step is a pure function of its own counters::

    phase = first i whose target is not reached, else RL (= len(phases))
        collect phase i:  done once N  >= Σ_{collect j ≤ i} <phase j's episodes field>
        offline phase i:  done once k  >= Σ_{offline j ≤ i} phase j's steps
    (N = completed episodes, the episode budget's counter; k = offline steps done)

    collect phase:  its controller acts (OU noise added if it says so), env step, replay,
                    episode counted against N_total; no learning
    offline phase:  the env is held (nothing stored, no step counted), one ``update``, k += 1
    RL:             the core's collect (the actor) and its ``learn``

Counts of episodes are ``HParams`` (sweepable in one compile: they are only compared with
N); offline step counts are static. Under ``vmap`` the phase is batched, so ``lax.switch``
computes every phase's body at every step and selects (and batches all its operands, so a
``cond`` inside a branch becomes a select too): an agent's results do not depend on its
neighbours (vmapped = alone), but a step costs the sum of the bodies: for LfD one
imitation step (an actor forward/backward), one critic step and the RL update, for MCP+MF
also the MPC (K·H model calls) and the model and actor fits. So a schedule with a gate
(``Schedule.gated``: LfD, MCP+MF) computes its heavy bodies *before* the switch, each under
``lax.cond`` on a flag that is the same for all agents of the population: a
``Phase(gated=True)``'s update, the schedule's ``precompute`` (work shared by several
collect phases, MCP+MF's MPC action) and the RL update (``rl_learn``, RL being the last
phase). Under ``vmap`` such a cond stays a real branch, and so do the conds inside the RL
update (the learner's warm-up, TD3's actor delay: their step index is unbatched there).

The flags (``chunk_gate``, computed once per chunk outside the ``vmap`` from every agent's
counters, ``population_gate``): gate[i] is on iff some agent may be in phase i at some step
of the chunk's ``TrainConfig.chunk_steps`` scan steps. Agent a, in phase p_a with k_a
offline steps done at the chunk's start, may be iff::

    p_a <= i                                     phases only advance
    offline_before[i] - k_a < chunk_steps        offline_before[i] = Σ steps of the offline
                                                 phases before i (static)

because an agent in phase i has done every offline phase before it, and k grows by at most
one a scan step (exactly one in an offline phase, whatever the agent's state; zero in a
collect phase). A collect phase may end at any step, so it bounds nothing. Agents counted:
the live ones (N < N_total), and for RL also the real agents that have finished (they stay
in RL and execute its update with zero learning rates: skipping it would move their key
and Adam moments differently). Padding agents (``devices.freeze_padding``: N = N_total from
the start, while their k still walks them through the offline phases into RL) never count:
``population_functions`` passes the number of real agents. The gate is then on whenever
some agent's selected branch reads the body, and an unselected branch's result is
discarded, so gating never changes what any agent computes (tested bit for bit against
the same program with every gate forced on). LfD at the paper's sizes (5,000 imitation +
1,000 warm-up steps, chunk 1,000): a demonstration step computes the imitation step only
(it may start at any step); the warm-up and the RL update wait for the chunk that can
reach them. ``updates_per_step`` changes nothing here: it is the number of learner
updates inside one RL step, while every phase advances by scan steps.

To add a baseline: write its ``Phase``s (a controller for each collect phase, an update for
each offline phase), the extra per-agent state its phases need (``Schedule.init``), and
register its factory in ``trainer.SCHEDULES``.
"""

from __future__ import annotations

import dataclasses
from collections.abc import Callable
from typing import Any, NamedTuple

import jax
import jax.numpy as jnp
import numpy as np
from flax import struct

from advisor_jax.agent.config import HParams
from advisor_jax.agent.learner import nan_like

Metrics = dict[str, jax.Array]


class Control(NamedTuple):
    """What a collect phase's controller executes this step (before noise and clipping)."""

    action: jax.Array  # [E, 2]
    actor_fired: jax.Array  # [E] bool: the actor chose the action (firing-rate log)
    noise: jax.Array | float  # 1.0: add the OU noise (advisor, actor); 0.0: none
    label: jax.Array | None = None  # [E, 2] stored as Transition.advisor_action (None: a_adv)


@dataclasses.dataclass(frozen=True)
class Phase:
    """One phase before RL: a collect phase (``episodes`` and ``act``) or an offline phase
    (``steps`` and ``update``)."""

    name: str
    episodes: str | None = None
    """Collect phase: the ``HParams`` field holding its episode count."""
    act: Callable[..., Control] | None = None
    """Collect phase: (state, obs [E, 20], actor_action, advisor_action, key, hp, extra) ->
    Control; ``extra`` is the schedule's ``precompute`` output (None without one)."""
    steps: int = 0
    """Offline phase: scan steps it takes (static)."""
    update: Callable[..., tuple[Any, Metrics, jax.Array]] | None = None
    """Offline phase: (state, hp) -> (state, metrics, nonfinite); one step, pure."""
    gated: bool = False
    """Offline phase: run ``update`` under ``lax.cond`` on the population's flag for this
    phase (``chunk_gate``), so that it is skipped while no agent can be in it during the
    chunk. A schedule with a gated phase (or a ``precompute``) gates the RL update too."""

    def __post_init__(self):
        collect = self.episodes is not None and self.act is not None
        offline = self.update is not None and self.steps > 0
        if collect == offline:
            raise ValueError(f"phase {self.name!r} must be a collect or an offline phase")


class Schedule(NamedTuple):
    """A baseline's phases before RL and the extra state they carry."""

    phases: tuple[Phase, ...]
    init: Callable[[Any, jax.Array], Any]  # (LearnerState, key) -> the phases' own state
    precompute: Callable[..., Any] | None = None
    """(state, obs [E, 20], key, hp) -> extra, passed to every collect phase's ``act``;
    computed under ``lax.cond``, only while some agent may be in a phase of ``uses``."""
    uses: tuple[int, ...] = ()
    """Indices of the phases that read ``precompute``'s output."""

    @property
    def gated(self) -> bool:
        """Whether ``chunk`` takes the population's flags (``chunk_gate``); the RL update is
        then gated as well."""
        return self.precompute is not None or any(p.gated for p in self.phases)

    @property
    def names(self) -> tuple[str, ...]:
        """Phase names, RL last: ``phase`` indexes this tuple."""
        return (*(p.name for p in self.phases), "rl")

    @property
    def offline_steps(self) -> int:
        return sum(p.steps for p in self.phases)


@struct.dataclass
class PhaseState:
    """Per-agent state of a baseline's phases (``PriorState.prior``)."""

    offline_steps: jax.Array  # () int32, k: offline steps done
    data: Any  # the baseline's own (LfD: the imitation's Adam state; MCP+MF: McpData)


def init_state(schedule: Schedule, learner_state, key: jax.Array) -> PhaseState:
    return PhaseState(offline_steps=jnp.int32(0), data=schedule.init(learner_state, key))


def phase_index(schedule: Schedule, episodes: jax.Array, offline: jax.Array, hp: HParams):
    """The agent's phase: index into ``schedule.names`` (int32; RL = len(phases))."""
    done, n_target, k_target = [], 0.0, 0
    for phase in schedule.phases:
        if phase.act is not None:
            n_target = n_target + getattr(hp.prior, phase.episodes)
            done.append(episodes >= n_target)
        else:
            k_target += phase.steps
            done.append(offline >= k_target)
    done = jnp.stack(done)
    return jnp.where(jnp.all(done), len(done), jnp.argmin(done)).astype(jnp.int32)


def offline_before(schedule: Schedule) -> np.ndarray:
    """[len(phases) + 1] int: the offline steps of the phases before phase i (static), i.e.
    the value k must reach before an agent can be in phase i (RL last)."""
    k, out = 0, []
    for phase in schedule.phases:
        out.append(k)
        if phase.update is not None:
            k += phase.steps
    return np.asarray([*out, k], np.int64)


def chunk_gate(
    schedule: Schedule,
    phase: jax.Array,
    offline: jax.Array,
    live: jax.Array,
    chunk_steps: int,
    real: jax.Array | None = None,
) -> jax.Array:
    """[len(phases) + 1] bool: phase i may run at some step of the next chunk for some agent.

    Per agent (leading axis, or () for one): ``phase`` and ``offline`` (k) at the chunk's
    start, ``live`` whether it still plays (N < N_total), ``real`` whether it is one of the
    population's agents (False: a padding agent; None: all are). Agent a may be in phase i
    during the chunk's ``chunk_steps`` scan steps iff

        phase_a <= i                                   (phases only advance)
        offline_before[i] - k_a < chunk_steps          (k grows by one a scan step in an
                                                        offline phase, by none in a collect
                                                        phase)

    (a collect phase may end at any step, so it bounds nothing). Gate i is on iff some live
    agent may; for RL also iff some real agent has finished (it stays in RL, executing its
    frozen update: skipping it would change its carried state, the key and Adam moments). A
    padding agent never turns a gate on. Compute it outside the ``vmap`` over agents: it
    must be the same for all (unbatched) for ``lax.cond`` to skip work."""
    n = len(schedule.phases) + 1
    phase, offline, live = (jnp.atleast_1d(x) for x in (phase, offline, live))
    real = jnp.ones_like(live) if real is None else jnp.atleast_1d(real)
    reach = (phase[:, None] <= jnp.arange(n)) & (
        jnp.asarray(offline_before(schedule))[None, :] - offline[:, None] < chunk_steps
    )  # [agents, n]
    counts = live[:, None] | (real[:, None] & (jnp.arange(n) == n - 1))
    return jnp.any(reach & counts, axis=0)


def population_gate(
    schedule: Schedule, state, hp: HParams, n_total: int, chunk_steps: int, n_real=None
) -> jax.Array:
    """``chunk_gate`` of a population's stacked state (or of one agent's); ``n_real``: the
    first ``n_real`` agents are real, the rest padding (None: all real)."""
    index = phase_index
    if state.episodes.ndim:
        index = jax.vmap(phase_index, in_axes=(None, 0, 0, 0))
    offline = state.prior.offline_steps
    phase = index(schedule, state.episodes, offline, hp)
    real = None
    if n_real is not None:
        real = jnp.arange(jnp.atleast_1d(state.episodes).shape[0]) < n_real
    return chunk_gate(schedule, phase, offline, state.episodes < n_total, chunk_steps, real)


def control(schedule, phase, state, obs, actor_action, advisor_action, key, hp, gate=None):
    """(Control, acting) of this step: the phase's controller; the actor in RL; in an
    offline phase ``acting`` is False and the env must be held. ``gate``: ``chunk_gate``
    (needed when the schedule has a ``precompute``)."""
    n_envs = obs.shape[0]
    actor = Control(actor_action, jnp.ones(n_envs, bool), jnp.float32(1.0), advisor_action)
    extra = None
    if schedule.precompute is not None:
        key, k_pre = jax.random.split(key)
        on = jnp.any(gate[jnp.asarray(schedule.uses)])
        shape = jax.eval_shape(schedule.precompute, state, obs, k_pre, hp)
        extra = jax.lax.cond(
            on, schedule.precompute, lambda *_: nan_like(shape), state, obs, k_pre, hp
        )

    def branch(phase_def):
        if phase_def is None or phase_def.act is None:  # RL, or offline (ignored)
            return lambda *_: actor
        return lambda *a: _as_control(phase_def.act(*a), n_envs, advisor_action)

    keys = [p.act if p.act is not None else "actor" for p in schedule.phases] + ["actor"]
    index, unique = _branch_table(schedule, phase, keys)
    branches = [branch(schedule.phases[keys.index(k)] if k != "actor" else None) for k in unique]
    chosen = jax.lax.switch(
        index, branches, state, obs, actor_action, advisor_action, key, hp, extra
    )
    offline = jnp.asarray([p.act is None for p in schedule.phases] + [False])
    return chosen, ~offline[phase]


def _as_control(c: Control, n_envs: int, advisor_action: jax.Array) -> Control:
    return Control(
        action=c.action,
        actor_fired=jnp.broadcast_to(jnp.asarray(c.actor_fired, bool), (n_envs,)),
        noise=jnp.asarray(c.noise, jnp.float32),
        label=advisor_action if c.label is None else c.label,
    )


def learn(schedule, phase, state, hp, step_index, rl_learn, gate=None):
    """This step's learning: nothing in a collect phase, the phase's update (k += 1) in an
    offline phase, ``rl_learn(state, hp, step_index)`` in RL. Returns (state, metrics,
    nonfinite) with one metrics dict for all phases (NaN where a phase computes nothing)
    and ``train/phase``. With ``gate`` (``chunk_gate``), a gated phase's update and the RL
    update are computed before the switch, under ``lax.cond`` on their flags: only while
    some agent may be in a phase that runs them."""

    def idle(state, hp, step_index):
        return state, {}, jnp.zeros((), bool)

    keys = [p.update if p.update is not None else "idle" for p in schedule.phases] + ["rl"]
    index, unique = _branch_table(schedule, phase, keys)

    def offline(i, update):
        if schedule.phases[i].gated:
            same = [j for j, k in enumerate(keys) if k is update]  # phases sharing it
            update = _computed_if(jnp.any(gate[jnp.asarray(same)]), update, state, hp)

        def run(state, hp, step_index):
            state, metrics, bad = update(state, hp)
            prior = state.prior.replace(offline_steps=state.prior.offline_steps + 1)
            return state.replace(prior=prior), metrics, bad

        return run

    if gate is not None:  # RL is the last phase: gate[-1]
        rl_learn = _computed_if(gate[-1], rl_learn, state, hp, step_index)
    branches = [rl_learn if k == "rl" else idle if k == "idle" else offline(keys.index(k), k)
                for k in unique]  # fmt: skip
    shapes = {}
    for b in branches:
        shapes.update(jax.eval_shape(b, state, hp, step_index)[1])

    def complete(b):
        def run(*args):
            state, metrics, bad = b(*args)
            filled = {name: metrics[name] if name in metrics else nan_like(shape)
                      for name, shape in shapes.items()}  # fmt: skip
            return state, filled, bad

        return run

    state, metrics, bad = jax.lax.switch(
        index, [complete(b) for b in branches], state, hp, step_index
    )
    return state, {**metrics, "train/phase": phase}, bad


def _computed_if(on: jax.Array, body, state, *args):
    """``body(state, *args)`` -> (state, metrics, nonfinite), computed now under
    ``lax.cond(on, ...)`` (skipped: ``state`` unchanged, NaN metrics, not non-finite), as a
    branch for the switch that ignores its arguments.

    Outside the switch: under vmap a batched switch batches all its operands, and a cond
    inside a branch would become a select. Here ``on`` is unbatched (``chunk_gate``), so
    the cond really skips ``body`` while no agent can be in a phase that runs it; when on,
    the switch picks the result only for the agents in such a phase."""
    shape = jax.eval_shape(body, state, *args)
    result = jax.lax.cond(
        on, body, lambda s, *_: (s, nan_like(shape[1]), jnp.zeros((), bool)), state, *args
    )
    return lambda *_: result


def _branch_table(schedule: Schedule, phase: jax.Array, keys: list) -> tuple[jax.Array, list]:
    """(branch index, unique keys): a gated schedule (MCP+MF) compiles each distinct body
    once, however many rounds repeat it (``keys``: one per phase, RL last, compared by
    identity); an ungated one keeps one branch per phase, as it was built."""
    if not schedule.gated:
        return phase, keys
    unique = []
    for k in keys:
        if not any(k is u for u in unique):
            unique.append(k)
    table = jnp.asarray([next(j for j, u in enumerate(unique) if u is k) for k in keys],
                        jnp.int32)  # fmt: skip
    return table[phase], unique


def describe(schedule: Schedule) -> list[dict]:
    """The schedule for run.json: each phase's name and its episode-count field or steps."""
    out = [{"name": p.name, "episodes": p.episodes} if p.act else {"name": p.name,
            "steps": p.steps} for p in schedule.phases]  # fmt: skip
    return out + [{"name": "rl", "episodes": "the rest of episodes (N_total)"}]


def episode_phases(schedule: Schedule, hp: HParams, n_total: int) -> np.ndarray:
    """[agents, N_total] int8: the phase (index into ``schedule.names``) that played each
    episode, from the stacked hyperparameters (host side: metrics.npz, episodes.csv)."""
    collect = [(i, p) for i, p in enumerate(schedule.phases) if p.act is not None]
    counts = [np.atleast_1d(np.asarray(getattr(hp.prior, p.episodes), np.float64))
              for _, p in collect]  # fmt: skip
    n_agents = counts[0].size if counts else np.atleast_1d(np.asarray(hp.rl.gamma)).size
    episode = np.arange(n_total)[None, :]
    out = np.full((n_agents, n_total), len(schedule.phases), np.int8)  # RL
    ends = np.cumsum(counts, axis=0) if counts else []
    for (i, _), end in reversed(list(zip(collect, ends, strict=True))):  # first phase wins
        out = np.where(episode < end[:, None], np.int8(i), out)
    return out
