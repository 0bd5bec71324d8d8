"""The host loop: outputs on disk, parameters load back, resume, bad input."""

from __future__ import annotations

import json

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from advisor_jax import checkpoint
from advisor_jax.config import AgentConfig, HParams, parse_agent, validate_hparams
from advisor_jax.run import population_functions, run_training
from advisor_jax.sweep import agent_keys, build_population, parse_assignments
from tests.train.conftest import N_CHUNKS, TINY, agent_slice, run_chunks


@pytest.fixture(scope="module")
def finished_run(tmp_path_factory):
    out = tmp_path_factory.mktemp("run")
    summary = run_training(
        TINY,
        HParams(lr_actor=1e-3),
        {"beta": [0.01, 0.3]},
        seeds=[3],
        out_dir=out,
        eval_episodes=6,
        eval_arenas=("training",),
        checkpoint_every=1,
        progress=False,
    )
    return out, summary


def test_run_writes_every_output(finished_run):
    out, summary = finished_run
    for name in ("run.json", "eval.json", "metrics.npz", "episodes.csv", "learning_curve.png"):
        assert (out / name).is_file(), name
    saved = json.loads((out / "run.json").read_text())
    assert saved["status"] == "finished" and saved["agent"] == "ATD3+AfDP"
    assert [a["beta"] for a in saved["agents"]] == pytest.approx([0.01, 0.3])
    metrics = np.load(out / "metrics.npz")
    assert metrics["outcome"].shape == (2, TINY.episodes)
    assert np.all(metrics["outcome"] > 0)
    rows = (out / "episodes.csv").read_text().strip().splitlines()
    assert len(rows) == 1 + 2 * TINY.episodes
    ev = json.loads((out / "eval.json").read_text())["training"]
    assert len(ev["success"]) == 2 and ev["episodes"] == 6
    assert all(0.0 <= s <= 1.0 for s in ev["success"])


def test_saved_parameters_load_and_evaluate_identically(finished_run):
    from advisor_jax.evaluation_runs import evaluate_population

    out, summary = finished_run
    params = checkpoint.load_tree(out / "params")
    trainer = population_functions(TINY)[0]
    again = evaluate_population(
        params["actor"],
        trainer.policy_apply,
        arenas=("training",),
        episodes=6,
        key=jax.random.PRNGKey(10_000 + 3),
        max_episode_steps=TINY.max_episode_steps,
    )
    assert again["training"]["success"] == summary["evaluation"]["training"]["success"]


def test_existing_run_needs_resume(finished_run):
    out, _ = finished_run
    with pytest.raises(ValueError, match="--resume"):
        run_training(TINY, HParams(), {}, [0], out, progress=False)


def test_checkpoint_resume_equals_uninterrupted(population, tmp_path):
    """One chunk, checkpoint, restore, the remaining chunks == the straight run."""
    state_ref, hp, seeds = population
    _, init_fn, chunk_fn = population_functions(TINY)
    keys = agent_keys(seeds)
    state = run_chunks(init_fn, chunk_fn, keys, hp, n_chunks=1)
    checkpoint.save_step(tmp_path, TINY.chunk_steps, state)
    restored, step = checkpoint.restore_latest(tmp_path, jax.eval_shape(init_fn, keys))
    assert step == TINY.chunk_steps
    final = run_chunks(init_fn, chunk_fn, keys, hp, n_chunks=N_CHUNKS, state=restored, first=1)
    for i in range(4):
        for a, b in zip(
            jax.tree_util.tree_leaves(agent_slice(jax.device_get(final), i)),
            jax.tree_util.tree_leaves(agent_slice(state_ref, i)),
            strict=True,
        ):
            np.testing.assert_array_equal(np.asarray(a), np.asarray(b))


def test_corrupt_checkpoint_gives_clear_error(tmp_path):
    with pytest.raises(ValueError, match="no checkpoints"):
        checkpoint.restore_latest(tmp_path / "missing", {"a": jnp.zeros(2)})
    with pytest.raises(ValueError, match="no saved parameters"):
        checkpoint.load_tree(tmp_path / "nothing-here")


@pytest.mark.parametrize(
    "make, message",
    [
        (lambda: parse_agent("SAC"), "unknown agent 'SAC'"),
        (lambda: parse_agent("ADDPG+AfX"), "unknown advisor switch 'afx'"),
        (lambda: parse_agent("DDPG+AfP"), "AfP"),
        (lambda: AgentConfig(batch_size=2000, buffer_size=1000), "batch_size=2000"),
        (lambda: AgentConfig(actor_hidden=(0, 10)), "actor_hidden"),
        (lambda: validate_hparams(HParams(advisor_episodes=-1.0)), "advisor_episodes=-1"),
        (lambda: validate_hparams(HParams(eps_start=1.2)), "eps_start=1.2"),
        (lambda: validate_hparams(HParams(gamma=float("nan"))), "gamma=nan"),
        (lambda: parse_assignments(["bogus=1"]), "unknown hyperparameter 'bogus'"),
        (lambda: parse_assignments(["beta=abc"]), "non-numeric"),
        (lambda: build_population(HParams(), {"eps_start": [0.5, 1.5]}, [0]), r"agent 1"),
    ],
)
def test_bad_configuration_is_named(make, message):
    with pytest.raises(ValueError, match=message):
        make()
