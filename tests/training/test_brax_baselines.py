"""brax SAC and PPO as baseline agent types (issue 38): one CLI run of brax-SAC at CPU size
(compiled once for the module), the episode budget, the run directory, our evaluator,
TensorBoard, the report; a tiny brax-PPO run."""

from __future__ import annotations

import dataclasses
import json
import shutil

import jax
import numpy as np
import pytest

import envs
from advisor_jax.agent.brax_agents import (
    PpoSettings,
    SacSettings,
    default_settings,
    network_factory,
    parse_settings,
    policy_apply,
)
from advisor_jax.cli.main import main
from advisor_jax.evaluation.evaluate import make_evaluate
from advisor_jax.training.brax_baselines.episodes import Budget, EpisodeLog
from advisor_jax.training.brax_baselines.trainer import train_seed
from advisor_jax.training.population import eval_key
from advisor_jax.training.run_directory import load_agent_policy
from tests.analysis.fake_runs import write_run
from tests.training.event_files import scalars

EPISODES, H_MAX, EVAL = 60, 100, 32


@pytest.fixture(scope="module")
def sac_run(tmp_path_factory):
    root = tmp_path_factory.mktemp("brax")
    out, tb = root / "sac", root / "tb"
    main(["train", "--agent", "brax-SAC", "--preset", "quick", "--episodes", str(EPISODES),
          "--max-episode-steps", str(H_MAX), "--eval-episodes", str(EVAL), "--out", str(out),
          "--tensorboard", str(tb), "--no-progress"])  # fmt: skip
    return out, tb


def test_the_run_directory_is_the_usual_one(sac_run, capsys):
    out, _ = sac_run
    for name in ("run.json", "eval.json", "metrics.npz", "episodes.csv", "train_log.jsonl",
                 "params", "learning_curve.png"):  # fmt: skip
        assert (out / name).exists(), name
    assert not (out / "agents").exists()  # per-seed saves are folded into params/
    run = json.loads((out / "run.json").read_text())
    assert run["status"] == "finished" and run["kind"] == "brax" and run["agent"] == "brax-SAC"
    assert run["config"]["brax"] == json.loads(json.dumps(dataclasses.asdict(
        default_settings("brax-SAC", "quick"))))  # fmt: skip
    # The budget: never more than N_total episodes, and at most one short epoch fewer.
    (completed,) = run["episodes_completed"]
    assert EPISODES - 10 <= completed <= EPISODES
    metrics = np.load(out / "metrics.npz")
    assert metrics["outcome"].shape == (1, EPISODES)
    assert int((metrics["outcome"] > 0).sum()) == completed
    assert int(metrics["length"].sum()) <= run["env_steps_per_agent"][0]
    rows = [json.loads(line) for line in (out / "train_log.jsonl").read_text().splitlines()]
    assert rows[-1]["episodes"] >= EPISODES and all(r["agent"] == 0 for r in rows)


def test_it_learns_over_its_start(sac_run):
    """A few thousand env steps of brax SAC raise the deterministic policy's return, on our
    evaluator's episodes, above that of its initial network."""
    out, _ = sac_run
    apply, params = load_agent_policy(out, 0)
    evaluate = jax.jit(make_evaluate(envs.make_env("training", max_episode_steps=H_MAX),
                                     apply, EVAL))  # fmt: skip
    settings = default_settings("brax-SAC", "quick")
    initial = network_factory(settings)(20, 2).policy_network.init(jax.random.PRNGKey(0))
    start = {"obs_mean": np.zeros(20, np.float32), "obs_std": np.ones(20, np.float32),
             "policy": initial}  # fmt: skip
    trained = float(np.mean(evaluate(params, eval_key(0)).episode_return))
    untrained = float(np.mean(evaluate(start, eval_key(0)).episode_return))
    assert trained > untrained + 1.0, (trained, untrained)


def test_evaluate_repeats_eval_json(sac_run, capsys):
    out, _ = sac_run
    saved = json.loads((out / "eval.json").read_text())
    capsys.readouterr()
    main(["evaluate", "--policy", f"{out}:0", "--arena", "validation", "--json"])
    result = json.loads(capsys.readouterr().out.strip().splitlines()[-1])
    assert result["episodes"] == EVAL and result["eval_seed"] == 0
    assert result["success_rate"] == pytest.approx(saved["validation"]["success"][0], abs=1e-6)


def test_tensorboard_event_files_read_back(sac_run):
    _, tb = sac_run
    tags = scalars(tb)
    assert "agent0/episodes" in tags and "agent0/training/critic_loss" in tags
    steps = [step for step, _ in tags["agent0/episodes"]]
    assert steps == sorted(steps) and tags["agent0/episodes"][-1][1] >= EPISODES


def test_report_pools_the_brax_row_with_the_others(sac_run, tmp_path, capsys):
    out, _ = sac_run
    runs = tmp_path / "runs"
    runs.mkdir()
    shutil.copytree(out, runs / "sac")
    write_run(runs, "ours", "DDPG", [0, 1, 2], [0.6, 0.7, 0.8], preset_name="quick",
              eval_episodes=EVAL)  # fmt: skip
    main(["report", str(runs), "--out", str(tmp_path / "report"), "--items", "table1"])
    table = json.loads((tmp_path / "report" / "table1.json").read_text())
    agents = {p["agent"]: p for p in table["points"]}
    assert set(agents) == {"DDPG", "brax-SAC"}
    assert agents["brax-SAC"]["seeds"] == 1
    assert agents["brax-SAC"]["settings"] == {"max_episode_steps": H_MAX}


def test_a_second_call_with_resume_leaves_the_finished_run(sac_run, capsys):
    out, _ = sac_run
    before = (out / "run.json").read_bytes()
    main(["train", "--agent", "brax-SAC", "--preset", "quick", "--episodes", str(EPISODES),
          "--max-episode-steps", str(H_MAX), "--eval-episodes", str(EVAL), "--out", str(out),
          "--resume", "--no-progress"])  # fmt: skip
    assert "finished run" in capsys.readouterr().err
    assert (out / "run.json").read_bytes() == before


@pytest.mark.parametrize(
    ("args", "message"),
    [
        (["--hp", "beta=1"], "--hp does not apply to brax-SAC"),
        (["--batch-size", "64"], "--batch-size does not apply to brax-SAC"),
        (["--baseline", "nope=1"], "unknown setting 'nope' for brax-SAC"),
        (["--baseline", "hidden=0,64"], "positive integer widths"),
        (["--baseline", "learning_rate=fast"], "learning_rate='fast': expected float"),
        (["--seed", str(2**31)], "brax agents take seeds 0 .."),
    ],
)
def test_options_are_checked_in_one_line(tmp_path, capsys, args, message):
    out = tmp_path / "never"
    with pytest.raises(SystemExit) as stop:
        main(["train", "--agent", "brax-sac", "--out", str(out), *args])
    assert stop.value.code == 2 and not out.exists()
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and message in err[0], err


def test_settings_parse_and_check():
    base = default_settings("brax-PPO", "stable")
    assert isinstance(base, PpoSettings) and base.discounting == 0.9
    changed = parse_settings("brax-PPO", base, ["num_envs=8", "policy_hidden=16,16"])
    assert (changed.num_envs, changed.policy_hidden) == (8, (16, 16))
    with pytest.raises(ValueError, match="multiple of num_envs"):
        parse_settings("brax-PPO", base, ["num_envs=48"])
    assert default_settings("brax-SAC", "physical").max_replay_size == 50_000
    assert isinstance(default_settings("brax-SAC", "quick"), SacSettings)


def test_episode_log_counts_the_episodes_within_a_step_budget():
    log = EpisodeLog(num_envs=2)
    done = np.array([True, True])
    for step, outcome in ((4, (1, 2)), (0, (2, 0)), (9, (3, 1))):  # callbacks out of order
        log.add(step, done & (np.array(outcome) > 0), np.array(outcome), np.array([5, 6]),
                np.array([1.0, -2.0]), np.array([0.3, 0.4]))  # fmt: skip
    assert log.count(2) == 1 and log.count(10) == 3 and log.count(20) == 5
    arrays = log.arrays(10, n_total=4)  # the episodes of vectorised steps 0..4
    np.testing.assert_array_equal(arrays["outcome"], [2, 1, 2, 0])
    np.testing.assert_allclose(arrays["collision_speed"][:3], [0.3, np.nan, 0.4], rtol=1e-6)
    # Within (n_total / num_envs + 1) · h_max steps per env every env completed its share.
    assert Budget(n_total=500, num_envs=8, h_max=300).ceiling_steps == 64 * 300 * 8


def test_brax_ppo_trains_under_the_budget():
    settings = dataclasses.replace(default_settings("brax-PPO", "quick"), unroll_length=5)
    env = envs.make_brax_env("training", max_episode_steps=40)
    result = train_seed("brax-PPO", settings, env, seed=0, budget=Budget(4, 16, 40))
    assert result.episodes_completed <= 4 and result.env_steps % 16 == 0
    action = policy_apply(settings)(result.params, np.zeros((3, 20), np.float32))
    assert action.shape == (3, 2) and np.all((action[:, 0] >= 0) & (action[:, 0] <= 1))


def test_an_interrupted_run_resumes_at_its_first_unfinished_seed(tmp_path, monkeypatch):
    """Each finished seed is saved at once; Ctrl-C during the next one leaves status
    "interrupted", and --resume trains only the seeds not saved (brax not run here)."""
    from advisor_jax.training import interrupts
    from advisor_jax.training.brax_baselines import run as brax_run
    from advisor_jax.training.brax_baselines.request import BraxRequest
    from advisor_jax.training.brax_baselines.trainer import SeedResult

    trained = []

    def fake_seed(agent, settings, env, seed, budget, on_epoch):
        if seed == 1 and not trained.count(1) and len(trained) == 1:
            trained.append(1)
            raise interrupts.Interrupted(2)
        trained.append(seed)
        episodes = {"outcome": np.full(budget.n_total, envs.GOAL, np.int32),
                    "length": np.full(budget.n_total, 7, np.int32),
                    "episode_return": np.full(budget.n_total, 9.5, np.float32),
                    "collision_speed": np.full(budget.n_total, np.nan, np.float32)}  # fmt: skip
        params = {"obs_mean": np.full(20, seed, np.float32), "obs_std": np.ones(20, np.float32)}
        return SeedResult(params, episodes, 70 * (seed + 1), budget.n_total, 1.0, [])

    monkeypatch.setattr(brax_run, "train_seed", fake_seed)
    request = BraxRequest("brax-SAC", default_settings("brax-SAC", "quick"), "quick", "training",
                          10, 0, "kinematic", (0, 1, 2), tmp_path / "run", 0, ("training",),
                          0)  # fmt: skip
    with pytest.raises(interrupts.Interrupted) as stop:
        brax_run.run_brax_training(request, progress=False)
    assert "during agent 1 of 3: 1 finished agent saved" in stop.value.detail
    assert json.loads((tmp_path / "run" / "run.json").read_text())["status"] == "interrupted"
    summary = brax_run.run_brax_training(dataclasses.replace(request, resume=True),
                                         progress=False)  # fmt: skip
    assert trained == [0, 1, 1, 2] and summary["status"] == "finished"
    assert summary["env_steps_per_agent"] == [70, 140, 210]
    _, params = load_agent_policy(tmp_path / "run", 2)
    np.testing.assert_array_equal(params["obs_mean"], np.full(20, 2.0))


def test_the_motion_model_reaches_the_request(tmp_path):
    """--motion is a brax agent's option too: canonical in the request (run.json's config)."""
    from advisor_jax.training.brax_baselines.request import build_brax_run
    from advisor_jax.training.request import TrainArgs

    args = TrainArgs(agent="brax-SAC", motion="mjx", out=str(tmp_path / "run"))
    assert build_brax_run(args, None).motion == "mjx"
    args = dataclasses.replace(args, motion="mjx:wheel_torque_max=0.8")
    assert build_brax_run(args, None).motion == "mjx:wheel_torque_max=0.8"
    assert build_brax_run(dataclasses.replace(args, motion=None), None).motion == "kinematic"
