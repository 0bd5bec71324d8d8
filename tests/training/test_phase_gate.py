"""The population's gate (training/prior/phases.py, ``chunk_gate``): hand-made cases, no compile.

Gate i is on iff some agent may be in phase i at some step of the next chunk: a live agent
in phase <= i whose offline steps still to take before phase i are fewer than the chunk's
steps, or (RL) a real agent that has finished. The runs that check it against the phases
actually played, and a gated run against the same program with every gate on, are in
test_lfd.py and test_mcp.py.
"""

from __future__ import annotations

from types import SimpleNamespace

import jax
import jax.numpy as jnp
import numpy as np

from advisor_jax.agent.hparams import BaselineHParams, HParams, LfdHParams
from advisor_jax.training.prior import phases

CHUNK = 1000


def _update(state, hp):
    return state, {}, jnp.zeros((), bool)


def _act(*args):
    raise AssertionError("not called")


def _schedule(*parts) -> phases.Schedule:
    """parts: an int (an offline phase of that many steps) or a str (a collect phase whose
    episode count is that hyperparameter of the prior phases)."""
    made = [phases.Phase(f"c{i}", episodes=p, act=_act) if isinstance(p, str) else
            phases.Phase(f"o{i}", steps=p, update=_update, gated=True)
            for i, p in enumerate(parts)]  # fmt: skip
    return phases.Schedule(phases=tuple(made), init=lambda *_: None)


# LfD at the paper's sizes: demo (D episodes) -> imitate 5000 -> warmup 1000 -> rl.
LFD = _schedule("demo_episodes", 5000, 1000)
DEMO, IMITATE, WARMUP, RL = range(4)


def _gate(schedule, agents, chunk=CHUNK):
    """agents: (phase, offline steps done, live, real) per agent."""
    phase, offline, live, real = (jnp.asarray(x) for x in zip(*agents, strict=True))
    return np.asarray(phases.chunk_gate(schedule, phase, offline, live, chunk, real))


def test_offline_before():
    np.testing.assert_array_equal(phases.offline_before(LFD), [0, 0, 5000, 6000])
    mixed = _schedule("random_episodes", 1, 10, "mpc_episodes", 10, 7)
    np.testing.assert_array_equal(phases.offline_before(mixed), [0, 0, 1, 11, 11, 21, 28])


def test_an_agent_in_demo_with_6000_offline_steps_ahead_skips_warmup_and_rl():
    # The demonstrations may end at any step (no bound), so imitation may start in this
    # chunk; warm-up needs 5000 imitation steps first and RL 6000 offline steps: not in 1000.
    gate = _gate(LFD, [(DEMO, 0, True, True)])
    np.testing.assert_array_equal(gate, [True, True, False, False])


def test_an_agent_with_500_warmup_steps_left_turns_rl_on():
    gate = _gate(LFD, [(WARMUP, 5500, True, True)])
    np.testing.assert_array_equal(gate, [False, False, True, True])


def test_the_bound_is_strict_at_the_chunk_length():
    # With exactly CHUNK offline steps left, RL's first step is the next chunk's first.
    left = lambda k: _gate(LFD, [(WARMUP, 6000 - k, True, True)])  # noqa: E731
    np.testing.assert_array_equal(left(CHUNK), [False, False, True, False])
    np.testing.assert_array_equal(left(CHUNK - 1), [False, False, True, True])
    np.testing.assert_array_equal(left(1), [False, False, True, True])
    # Inside imitation with 500 of its steps left: warm-up reachable, RL (1500 away) not.
    gate = _gate(LFD, [(IMITATE, 4500, True, True)])
    np.testing.assert_array_equal(gate, [False, True, True, False])
    # A smaller chunk: imitation's start is always reachable from demo, warm-up is not.
    gate = _gate(LFD, [(IMITATE, 4500, True, True)], chunk=500)
    np.testing.assert_array_equal(gate, [False, True, False, False])


def test_an_agent_in_rl_turns_only_rl_on():
    np.testing.assert_array_equal(_gate(LFD, [(RL, 6000, True, True)]), [False] * 3 + [True])


def test_padding_agents_are_ignored():
    # Padding agents (copies of agent 0, N = N_total from the start: not live, not real)
    # sit in imitation and later in RL; they never turn a gate on.
    for phase, k in ((IMITATE, 0), (WARMUP, 5999), (RL, 6000)):
        assert not _gate(LFD, [(phase, k, False, False)]).any()
    gate = _gate(LFD, [(DEMO, 0, True, True), (RL, 6000, False, False)])
    np.testing.assert_array_equal(gate, [True, True, False, False])


def test_a_finished_agent_keeps_rl_on():
    # A real agent that has played N_total episodes is in RL and still executes its frozen
    # RL update (its key and Adam moments move): RL stays on, nothing else.
    gate = _gate(LFD, [(RL, 6000, False, True), (DEMO, 0, True, True)])
    np.testing.assert_array_equal(gate, [True, True, False, True])
    # Without a padding mask every agent counts as real for RL (sound, only slower).
    gate = phases.chunk_gate(LFD, jnp.asarray([RL]), jnp.asarray([6000]),
                             jnp.asarray([False]), CHUNK)  # fmt: skip
    np.testing.assert_array_equal(gate, [False, False, False, True])


def test_the_population_ors_its_agents_and_earlier_phases_are_off():
    gate = _gate(LFD, [(WARMUP, 5500, True, True), (IMITATE, 100, True, True)])
    np.testing.assert_array_equal(gate, [False, True, True, True])
    # Phases only advance: nobody returns to demo.
    gate = _gate(LFD, [(IMITATE, 0, True, True)], chunk=10**6)
    np.testing.assert_array_equal(gate, [False, True, True, True])


def test_collect_phases_bound_nothing_offline_phases_add_up():
    # random -> normalise 1 -> fit 10 -> mpc -> fit 10 -> fit_actor 7 -> rl, chunk 15: from
    # the random phase the first mpc phase is 11 offline steps away (reachable), the second
    # fit ends 21 away: fit_actor (21 away) and RL (28 away) are not.
    mixed = _schedule("random_episodes", 1, 10, "mpc_episodes", 10, 7)
    gate = _gate(mixed, [(0, 0, True, True)], chunk=15)
    np.testing.assert_array_equal(gate, [True, True, True, True, True, False, False])
    gate = _gate(mixed, [(3, 11, True, True)], chunk=15)  # in mpc: fit_actor 10 away
    np.testing.assert_array_equal(gate, [False, False, False, True, True, True, False])


def test_one_agent_unbatched():
    gate = phases.chunk_gate(LFD, jnp.int32(WARMUP), jnp.int32(5500), jnp.bool_(True), CHUNK)
    np.testing.assert_array_equal(gate, [False, False, True, True])


def test_population_gate_reads_the_state_and_masks_padding():
    """From counters: agent 0 demonstrating (N 3 < D 30), agent 1 in warm-up 400 steps from
    RL, agent 2 a padding copy (N = N_total, k = 6000: in RL) masked by n_real = 2."""
    n_total = 60
    hp = jax.tree.map(
        lambda x: jnp.full((3,), x), BaselineHParams(rl=HParams(), prior=LfdHParams())
    )
    hp = hp.replace(prior=hp.prior.replace(demo_episodes=jnp.asarray([30.0, 30.0, 30.0])))

    def state(episodes, offline):
        prior = SimpleNamespace(offline_steps=jnp.asarray(offline, jnp.int32))
        return SimpleNamespace(episodes=jnp.asarray(episodes, jnp.int32), prior=prior)

    gate = phases.population_gate(LFD, state([3, 30, 60], [0, 5600, 6000]), hp, n_total, CHUNK, 2)
    np.testing.assert_array_equal(gate, [True, True, True, True])
    gate = phases.population_gate(LFD, state([3, 3, 60], [0, 0, 6000]), hp, n_total, CHUNK, 2)
    np.testing.assert_array_equal(gate, [True, True, False, False])  # the padding: ignored
    gate = phases.population_gate(LFD, state([3, 3, 60], [0, 0, 6000]), hp, n_total, CHUNK)
    np.testing.assert_array_equal(gate, [True, True, False, True])  # unmasked: counted
    gate = phases.population_gate(LFD, state([60, 60, 60], [6000] * 3), hp, n_total, CHUNK, 2)
    np.testing.assert_array_equal(gate, [False, False, False, True])  # finished: RL on
