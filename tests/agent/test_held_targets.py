"""The learner's held target networks (``LearnerState.target_nets``, ``Learner.hold``).

With each hidden layer one GEMM (GPUs), a training chunk builds the target networks' matrices
once per soft update instead of once per critic step. Held or not, the updates are the same
through several actor steps with a hard target update (τ = 1), where targets built before a
soft update would differ at once: bit for bit under XLA's default code generation
(``experiments/held_targets.py``, on a CPU and an H100), and to rounding under the suite's
CPU emitters (``tests/conftest.py``), where one element in hundreds may differ in its last
bit (``tests/compare.assert_same_training``). The modules hold nothing; a chunk takes and
returns the state without them, so stored states do not depend on the device.
"""

from __future__ import annotations

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from advisor_jax.agent import networks
from advisor_jax.agent.config import HParams, parse_agent, preset
from advisor_jax.agent.learner import make_learner
from advisor_jax.bench.learner_loop import SMALL, fill_replay
from advisor_jax.training import program
from advisor_jax.training.train import make_train
from tests.compare import assert_same_training

GEMM = networks.Layout(inputs_per_critic=False, layers_in_gemm=True)
SIZES = dict(actor_hidden=(16, 16), critic_state_hidden=24, critic_hidden=(16, 16))


def _assert_equal(a, b):
    for x, y in zip(jax.tree.leaves(a), jax.tree.leaves(b), strict=True):
        np.testing.assert_array_equal(np.asarray(x), np.asarray(y))


@pytest.fixture(scope="module")
def learner_and_replay():
    cfg = parse_agent("ATD3+AfDP", **{**SMALL, **SIZES, "batch_size": 32, "buffer_size": 256})
    return cfg, make_learner(cfg, layout=GEMM), fill_replay(cfg.buffer_size, jax.random.key(1))


@pytest.mark.parametrize("program", ["general", "steady"])
def test_held_targets_give_the_same_updates(learner_and_replay, program):
    cfg, learner, replay = learner_and_replay
    hp = HParams(tau=1.0)  # a hard update: stale targets would show at the next critic step

    def run(state, hold: bool):
        def update(state, u, update_fn=None):  # the general update, or the steady one's
            k_sample, k_critic = jax.random.split(jax.random.fold_in(jax.random.key(10), u))
            if update_fn is None:
                return learner.update(state, learner.sample(replay, k_sample), k_critic, hp, u)[:2]
            return update_fn(state, learner.sample(replay, k_sample), k_critic, hp)[:2]

        def block(state, u):  # d updates written out, the first with the actor step
            for j in range(cfg.delay):
                step = learner.update_with_actor if j == 0 else learner.update_critic_only
                state, metrics = update(state, u + j, step)
            return state, metrics

        body = update if program == "general" else block
        starts = jnp.arange(0, 3 * cfg.delay, 1 if program == "general" else cfg.delay)
        state = learner.hold(state) if hold else state
        state, metrics = jax.lax.scan(body, state, starts)  # three actor steps, critics between
        return learner.release(state), metrics

    start = jax.jit(learner.init)(jax.random.key(0))
    (held, _), (built, _) = (jax.jit(lambda s, h=h: run(s, h))(start) for h in (True, False))
    assert held.target_nets is None
    assert_same_training(held, built, start, "held targets")


def test_held_targets_are_the_targets_built_after_each_soft_update(learner_and_replay):
    cfg, learner, replay = learner_and_replay
    state = learner.hold(jax.jit(learner.init)(jax.random.key(0)))
    k_sample, k_critic = jax.random.split(jax.random.key(5))
    state, _, _ = jax.jit(learner.update_with_actor)(
        state, learner.sample(replay, k_sample), k_critic, HParams(tau=0.5)
    )
    rebuilt = learner.hold(learner.release(state))
    _assert_equal(state.target_nets, rebuilt.target_nets)
    # and they are the new targets' matrices, not the initial ones
    first = learner.hold(jax.jit(learner.init)(jax.random.key(0)))
    assert not np.array_equal(
        np.asarray(jax.tree.leaves(first.target_nets)[0]),
        np.asarray(jax.tree.leaves(state.target_nets)[0]),
    )


def test_the_modules_hold_nothing(learner_and_replay):
    cfg = learner_and_replay[0]
    learner = make_learner(cfg, layout=networks.MODULES)
    state = learner.init(jax.random.key(0))
    assert learner.hold(state).target_nets is None


@pytest.mark.parametrize("held_critics", [False, True])
def test_a_chunk_takes_and_returns_the_state_without_held_networks(held_critics):
    cfg, hp = preset("quick", "ATD3+AfDP", **SIZES)
    trainer = make_train(cfg, layout=GEMM._replace(held_critics=held_critics))
    state = jax.eval_shape(trainer.init, jax.random.key(0))
    out, _ = jax.eval_shape(trainer.chunk, state, hp, jnp.int32(0))
    assert out.learner.target_nets is None and out.learner.held is None
    assert jax.tree.structure(out) == jax.tree.structure(state)  # flax trees (agent/held_critics)


def test_every_program_but_the_latency_bound_one_of_fp32_learners_holds_its_targets(monkeypatch):
    assert [program.holds_networks(p) for p in program.PROGRAMS] == [True, True, False]
    assert program.holds_networks("latency-bound", "bf16")
    assert not program.holds_networks("latency-bound", "fp32")
    assert program.holds_networks("general", "bf16") and program.holds_networks("steady")
    built = {}

    def recording(cfg, steady, layout, hold_targets, free_store):
        built[steady] = hold_targets
        return make_train(cfg, steady, layout, hold_targets, free_store)

    monkeypatch.setattr(program, "make_train", recording)
    cfg = preset("quick", "ATD3+AfDP", **SIZES)[0]
    for name in program.PROGRAMS:
        program.population_functions(cfg, program=name)
        assert built.pop(name != "general") == program.holds_networks(name)
