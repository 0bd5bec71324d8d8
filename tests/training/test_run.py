"""The host loop: outputs on disk, parameters load back, resume, bad input."""

from __future__ import annotations

import dataclasses
import json

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from advisor_jax.agent.config import (
    AgentConfig,
    HParams,
    TrainConfig,
    parse_agent,
    preset,
    validate_hparams,
)
from advisor_jax.evaluation.evaluate import evaluate_population, population_evaluator
from advisor_jax.training import checkpoint, reporting
from advisor_jax.training.host_loop import run_training
from advisor_jax.training.population import agent_keys, build_population, parse_assignments
from advisor_jax.training.program import population_functions
from tests.training.conftest import N_CHUNKS, TINY, agent_slice, run_chunks

QUICK = dataclasses.replace(
    preset("quick")[0], episodes=25, chunk_steps=500, snapshot_episodes=(10,)
)
EVAL_EPISODES = 50


@pytest.fixture(scope="module")
def finished_run(tmp_path_factory):
    """A short CPU run of ATD3+AfDP (quick preset, 2 seeds, 25 episodes each)."""
    out = tmp_path_factory.mktemp("run")
    summary = run_training(
        QUICK,
        preset("quick")[1],
        {},
        seeds=[0, 1],
        out_dir=out,
        eval_episodes=EVAL_EPISODES,
        eval_arenas=("training",),
        checkpoint_every=0,
        progress=False,
    )
    return out, summary


@pytest.fixture(scope="module")
def quick_evaluators():
    """The run's evaluation (training arena, EVAL_EPISODES), compiled once for these tests."""
    return {"training": population_evaluator("training", EVAL_EPISODES, QUICK.agent.actor_hidden)}


def test_short_cpu_run_beats_its_untrained_actor(finished_run, quick_evaluators):
    _, summary = finished_run
    _, init_fn, _ = population_functions(QUICK)
    untrained = init_fn(agent_keys([0, 1]))  # the same initial actors, before training
    before = evaluate_population(
        quick_evaluators,
        untrained.learner.actor,
        key=jax.random.PRNGKey(10_000),  # the run's evaluation episodes (seed 0)
    )["training"]["success"]
    after = summary["evaluation"]["training"]["success"]
    assert np.mean(after) >= np.mean(before) + 0.15, (before, after)
    assert min(after) > max(before), (before, after)


def test_run_writes_every_output(finished_run):
    out, summary = finished_run
    for name in ("run.json", "eval.json", "metrics.npz", "episodes.csv", "learning_curve.png"):
        assert (out / name).is_file(), name
    saved = json.loads((out / "run.json").read_text())
    assert saved["status"] == "finished" and saved["agent"] == "ATD3+AfDP"
    assert [a["seed"] for a in saved["agents"]] == [0, 1]
    assert saved["program"] == "general"  # picked here (a CPU's program), recorded
    metrics = np.load(out / "metrics.npz")
    assert metrics["outcome"].shape == (2, QUICK.episodes)
    assert np.all(metrics["outcome"] > 0)
    assert np.all((metrics["firing_rate"] >= 0) & (metrics["firing_rate"] <= 1))
    rows = (out / "episodes.csv").read_text().strip().splitlines()
    assert len(rows) == 1 + 2 * QUICK.episodes
    ev = json.loads((out / "eval.json").read_text())["training"]
    assert len(ev["success"]) == 2 and ev["episodes"] == EVAL_EPISODES
    log = [
        json.loads(line, parse_constant=lambda c: pytest.fail(f"{c} in train_log.jsonl"))
        for line in (out / "train_log.jsonl").read_text().splitlines()
    ]
    assert log and all(line["loss/critic"] is None or line["loss/critic"] >= 0 for line in log)


def test_learner_diagnostics_per_agent(finished_run):
    """train_log.jsonl and metrics.npz hold every diagnostic once per agent and chunk, the
    per-agent values average to the line's population mean, and diagnostics.png is drawn."""
    out, _ = finished_run
    log = [json.loads(t) for t in (out / "train_log.jsonl").read_text().splitlines()]
    names = ("loss/critic", "advisor/replaced", "diag/grad_q_rms", "diag/step", "diag/saturated")
    last = log[-1]
    for name in names:
        per_agent = last["per_agent"][name]
        assert len(per_agent) == 2 and all(v is not None for v in per_agent), name
        assert np.mean(per_agent) == pytest.approx(last[name], rel=1e-6), name
    metrics = np.load(out / "metrics.npz")
    np.testing.assert_array_equal(metrics["log/step"], [line["step"] for line in log])
    series = metrics["log/diag/grad_q_rms"]
    assert series.shape == (2, len(log))
    np.testing.assert_allclose(series[:, -1], last["per_agent"]["diag/grad_q_rms"])
    assert (out / "diagnostics.png").is_file()


def test_snapshot_actor_is_saved_and_evaluated_on_the_same_episodes(finished_run, quick_evaluators):
    """--snapshot-episodes 10: params/ holds each agent's actor of episode 10, and
    eval_episode10.json (and run.json) its evaluation on eval.json's episodes."""
    out, summary = finished_run
    params = checkpoint.load_tree(out / "params")
    snapshot = jax.tree_util.tree_map(lambda p: np.asarray(p)[:, 0], params["actor_snapshots"])
    at_10 = json.loads((out / "eval_episode10.json").read_text())
    assert at_10 == summary["evaluation_at_episode"]["10"]
    again = evaluate_population(quick_evaluators, snapshot, key=jax.random.PRNGKey(10_000))
    assert again["training"]["success"] == at_10["training"]["success"]
    moved = [
        np.abs(np.asarray(a) - np.asarray(b)).max()
        for a, b in zip(
            jax.tree_util.tree_leaves(snapshot),
            jax.tree_util.tree_leaves(params["actor"]),
            strict=True,
        )
    ]
    assert max(moved) > 1e-3  # 15 more episodes of updates: not the final actor


def test_chunk_line_is_strict_json_without_updates():
    metrics = {"loss/actor": np.full((2, 4), np.nan), "loss/critic": np.array([np.inf, 2.0])}
    line = reporting.chunk_line(500, 1.0, np.array([3, 4]), metrics)
    assert line["loss/actor"] is None and line["loss/critic"] == 2.0
    assert line["per_agent"] == {"loss/actor": [None, None], "loss/critic": [None, 2.0]}
    json.dumps(line, allow_nan=False)


def test_saved_parameters_load_and_evaluate_identically(finished_run, quick_evaluators):
    out, summary = finished_run
    params = checkpoint.load_tree(out / "params")
    again = evaluate_population(quick_evaluators, params["actor"], key=jax.random.PRNGKey(10_000))
    assert again["training"]["success"] == summary["evaluation"]["training"]["success"]


def test_export_cli_writes_a_policy_the_runner_accepts(finished_run, tmp_path):
    from advisor_jax.cli.main import main
    from advisor_jax.runner.policy import load_policy

    out, _ = finished_run
    main(["export", str(out), "--agent", "1", "--out", str(tmp_path / "policy")])
    policy = load_policy(tmp_path / "policy")
    assert policy.meta["config"]["agent"] == "ATD3+AfDP"
    assert policy.meta["config"]["seed"] == 1
    assert policy.meta["env"]["arena"] == "training"
    record = json.loads((out / "run.json").read_text())["advisor"]
    assert policy.meta["config"]["advisor"] == record and record["spec"] == "rule"
    with pytest.raises(SystemExit) as exit_info:
        main(["export", str(out), "--agent", "7", "--out", str(tmp_path / "bad")])
    assert exit_info.value.code == 2


def test_existing_run_needs_resume(finished_run):
    out, _ = finished_run
    with pytest.raises(ValueError, match="--resume"):
        run_training(QUICK, HParams(), {}, [0], out, progress=False)


def test_checkpoint_resume_equals_uninterrupted(population, tiny_functions, tmp_path):
    """One chunk, checkpoint, restore, the remaining chunks == the straight run."""
    state_ref, hp, seeds = population
    _, init_fn, chunk_fn = tiny_functions
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
        (lambda: TrainConfig(episodes=10, snapshot_episodes=(10,)), r"snapshot_episodes.*\[10\]"),
        (lambda: TrainConfig(snapshot_episodes=(200, 100)), r"increasing.*\[200, 100\]"),
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


def test_reevaluate_on_the_runs_own_eval_seed_gives_its_eval_json(finished_run, quick_evaluators):
    from advisor_jax.training.run_directory import reevaluate

    out, _ = finished_run
    again = reevaluate(out, 0, EVAL_EPISODES, ("training",), quick_evaluators)
    assert again == json.loads((out / "eval.json").read_text())
    other = reevaluate(out, 8, EVAL_EPISODES, ("training",), quick_evaluators)["training"]
    assert len(other["success"]) == 2 and other["episodes"] == EVAL_EPISODES
    with pytest.raises(ValueError, match="eval_seed -1"):
        reevaluate(out, -1, EVAL_EPISODES, ("training",), quick_evaluators)
