"""``advisor_jax.bench.learner_loop`` times the update step training runs: on GPUs the
steady program's blocks of d updates (the first with the actor step), with no conditional, else a
``lax.cond`` per update. Both loops must compute the same updates."""

from __future__ import annotations

import jax
import numpy as np

from advisor_jax.agent.config import parse_agent
from advisor_jax.bench import learner_loop

TINY_LEARNER = parse_agent(
    "ATD3+AfDP", actor_hidden=(16, 16), critic_state_hidden=32, critic_hidden=(32, 32),
    buffer_size=256, batch_size=32, policy_delay=2,
)  # fmt: skip


def test_the_block_loop_computes_the_conditional_loops_updates():
    keys = jax.random.split(jax.random.PRNGKey(0), 2)
    out = {}
    for steady in (False, True):
        learner, loop = learner_loop.make_update_loop(TINY_LEARNER, 6, steady=steady)
        states = jax.jit(jax.vmap(learner.init))(keys)
        replays = jax.vmap(learner_loop.fill_replay, in_axes=(None, 0))(256, keys)
        out[steady] = jax.device_get(loop(states, replays, keys))
    general, steady = out[False], out[True]
    assert general.actor_updates.tolist() == steady.actor_updates.tolist() == [3, 3]
    assert general.critic_updates.tolist() == [6, 6]
    for x, y in zip(jax.tree.leaves(general), jax.tree.leaves(steady), strict=True):
        np.testing.assert_allclose(x, y, rtol=1e-4, atol=1e-6)


def test_a_loop_that_is_not_whole_blocks_keeps_the_conditional():
    learner, loop = learner_loop.make_update_loop(TINY_LEARNER, 5, steady=True)
    keys = jax.random.split(jax.random.PRNGKey(0), 1)
    states = jax.jit(jax.vmap(learner.init))(keys)
    replays = jax.vmap(learner_loop.fill_replay, in_axes=(None, 0))(256, keys)
    assert jax.device_get(loop(states, replays, keys)).actor_updates.tolist() == [3]


def test_the_report_records_its_command(tmp_path, monkeypatch):
    # Each row of results/bench_learner.json names the command that measured it.
    import json
    import sys

    from tests.experiments.scripts import load_script

    argv = ["--small", "--agents", "1", "--updates", "2", "--precision", "fp32", "--out"]
    monkeypatch.setattr(sys, "argv", ["bench_learner.py", *argv, str(tmp_path)])
    load_script("bench_learner").main()
    command = json.loads((tmp_path / "bench_learner.json").read_text())["command"]
    assert command == f"python experiments/bench_learner.py {' '.join(argv)} {tmp_path}"
    assert f"Command: `{command}`" in (tmp_path / "bench_learner.md").read_text()
