"""The run's advisor (``training/advisor_source.py``, ``TrainConfig.advisor``): the default
trains as the bare rule did, a trained policy advises, the quality knobs are grid
points of one population, the advisor alone is evaluated on the agents' episodes, and
run.json's record is part of the run's identity."""

from __future__ import annotations

import dataclasses
import json

import jax
import jax.numpy as jnp
import numpy as np
import pytest

import envs
from advisor_jax.agent.advisors import tree_sha256
from advisor_jax.agent.networks import make_actor
from advisor_jax.evaluation.evaluate import make_evaluate
from advisor_jax.training import run_state
from advisor_jax.training.advisor_source import resolve_advisor
from advisor_jax.training.host_loop import run_training
from advisor_jax.training.population import agent_keys, eval_key
from advisor_jax.training.program import population_functions
from advisor_jax.training.run_directory import load_actor
from tests.compare import assert_same_training
from tests.training.conftest import RUN_HP, TINY, _population, agent_slice, run_chunks


def _bare_acting(apply, params):
    """What the core did before plug-in advisors: the advisor on the observation, nothing
    else (no view, clip, delay, noise or random draw; its key unused)."""
    batched = jax.vmap(apply, in_axes=(None, 0))
    return lambda quality, memory, obs, key: (batched(params, obs), memory)


def test_the_default_trains_as_the_bare_rule(population, initial_state, monkeypatch):
    """The default advisor through the interface (knobs at zero, its own key folded in, its
    memory carried) leaves every agent's training as the rule called directly: the knobs'
    arithmetic is exact identities at zero. The two are different programs, so they agree
    up to the order XLA sums in (``assert_same_training``: every integer leaf, counters,
    outcomes, keys, identical; floats to rounding). Under XLA's default CPU code generation
    they agree bit for bit; the suite's older emitters (tests/conftest.py) lower the rule's
    dot product beside the knobs' operations to a last-bit different sum."""
    import advisor_jax.training.train as train_module

    monkeypatch.setattr(train_module, "make_acting", _bare_acting)
    _, init_fn, chunk_fn = population_functions(TINY)
    hp, seeds = _population()
    bare = jax.device_get(run_chunks(init_fn, chunk_fn, agent_keys(seeds), hp))
    state = population[0]
    for name in ("log", "learner", "replay", "env", "noise", "key", "episodes", "diverged"):
        assert_same_training(
            getattr(state, name), getattr(bare, name), getattr(initial_state, name), name
        )


def _env():
    return envs.make_env(TINY.arena, max_episode_steps=TINY.max_episode_steps)


def test_a_trained_run_is_an_advisor(straight_run):
    env = _env()
    advisor = resolve_advisor(f"{straight_run}:1", env)
    _, row, params = load_actor(straight_run, 1)
    assert advisor.kind == "run" and advisor.origin == {
        "agent": "ATD3+AfDP", "index": 1, "seed": row["seed"]
    }  # fmt: skip
    assert advisor.record()["params_sha256"] == tree_sha256(params)
    obs = jnp.asarray(np.random.default_rng(0).uniform(0, 1, (8, 20)), jnp.float32)
    want = make_actor(TINY.agent.actor_hidden).apply(params, obs)
    got = jax.vmap(advisor.apply, in_axes=(None, 0))(advisor.params, obs)
    np.testing.assert_allclose(np.asarray(got), np.asarray(want), atol=1e-6)
    assert resolve_advisor(str(straight_run), env).origin["index"] == 0  # RUN alone: agent 0
    with pytest.raises(ValueError, match="--agent 9 is out of range"):
        resolve_advisor(f"{straight_run}:9", env)
    with pytest.raises(ValueError, match="unknown advisor 'no/such/run:0': give rule"):
        resolve_advisor("no/such/run:0", env)


@pytest.fixture(scope="module")
def advised_run(straight_run, tmp_path_factory):
    """Two seeds × advisor_random ∈ {0, 1} advised by agent 1 of the straight run, its
    advisor evaluated alone on the agents' episodes."""
    out = tmp_path_factory.mktemp("advised")
    cfg = dataclasses.replace(TINY, advisor=f"{straight_run}:1")
    run_training(
        cfg, RUN_HP, {"advisor_random": [0.0, 1.0]}, [0, 1], out, eval_episodes=8,
        eval_arenas=("training",), checkpoint_every=0, progress=False, eval_advisor=True,
    )  # fmt: skip
    return out, cfg


def test_a_trained_policy_advises_under_its_knobs(advised_run):
    out, cfg = advised_run
    summary = run_state.read_run_json(out / "run.json")  # the identity holds the advisor
    record = summary["advisor"]
    assert record["spec"] == cfg.advisor and record["kind"] == "run"
    assert summary["identity"] == run_state.run_identity(
        summary["config"], summary["agents"], record
    )
    assert summary["identity"] != run_state.run_identity(summary["config"], summary["agents"])
    assert [a["advisor_random"] for a in summary["agents"]] == [0.0, 0.0, 1.0, 1.0]


def test_the_advisor_alone_is_scored_on_the_agents_episodes(advised_run):
    out, cfg = advised_run
    advice = json.loads((out / "eval_advisor.json").read_text())["training"]
    assert advice["episodes"] == 8
    assert advice["success"][0] == advice["success"][1]  # same knobs, same episodes and draws
    assert advice["timeout"][2] == advice["timeout"][3]
    env = _env()
    _, _, params = load_actor(cfg.advisor.rpartition(":")[0], 1)
    alone = jax.jit(make_evaluate(env, make_actor(TINY.agent.actor_hidden).apply, 8))(
        params, eval_key(0)
    )
    assert advice["success"][0] == pytest.approx(float(np.mean(np.asarray(alone.outcome) == 1)))
    summary = json.loads((out / "run.json").read_text())
    assert summary["advisor_evaluation"] == json.loads((out / "eval_advisor.json").read_text())


def test_resume_refuses_a_changed_advisor_and_an_edited_record(advised_run, tmp_path):
    out, _ = advised_run
    saved = json.loads((out / "run.json").read_text())
    changed = {**saved, "advisor": {**saved["advisor"], "params_sha256": "0" * 64}}
    with pytest.raises(ValueError, match="its advisor's parameters changed since it started"):
        run_state.resume_record(out / "run.json", changed)
    edited = tmp_path / "run.json"
    edited.write_text(json.dumps(changed))
    with pytest.raises(ValueError, match="does not match its own config, agents and advisor"):
        run_state.read_run_json(edited)


def test_the_advisor_actions_stored_are_the_trained_policy_s(advised_run, straight_run):
    """a_adv in the replay (what AfD selected and AfP compares) is the teacher's action at
    advisor_random = 0, and mostly not at 1 (a uniform random action)."""
    from advisor_jax.training import checkpoint

    out, cfg = advised_run
    summary = json.loads((out / "run.json").read_text())
    trainer = population_functions(cfg)[0]  # built, not compiled
    abstract = jax.eval_shape(jax.vmap(trainer.init), agent_keys([0, 1, 0, 1]))
    state, _ = checkpoint.restore_latest(out / "checkpoints", abstract, run=summary["identity"])
    _, _, teacher = load_actor(straight_run, 1)
    actor = make_actor(TINY.agent.actor_hidden)
    for agent, same in ((0, True), (2, False)):
        data = agent_slice(state.replay.data, agent)
        n = int(np.asarray(state.replay.size)[agent])
        want = np.asarray(actor.apply(teacher, jnp.asarray(data.obs[:n])))
        close = np.all(np.abs(np.asarray(data.advisor_action[:n]) - want) < 1e-5, axis=-1)
        assert close.all() if same else close.mean() < 0.05, (agent, close.mean())
