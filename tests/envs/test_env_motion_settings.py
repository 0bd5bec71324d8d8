"""The motion model travels with a policy: training config and CLI, evaluation, export and
the car runner use the model the policy was trained with (envs/motion.py)."""

from __future__ import annotations

import dataclasses
import json

import jax
import numpy as np
import pytest

import envs
from advisor_jax.agent.config import TrainConfig, train_config_from_dict
from advisor_jax.agent.networks import init_actor, make_actor
from advisor_jax.cli import main as cli
from advisor_jax.cli.policy_spec import policy_motion
from advisor_jax.cli.train import TrainArgs, build_run
from advisor_jax.deploy.export import export_policy
from advisor_jax.evaluation import evaluate as evaluate_module
from advisor_jax.runner.errors import PolicyError
from advisor_jax.runner.policy import load_policy
from advisor_jax.runner.policy_meta import config_hash, metadata_sha256

HIDDEN = (8, 8)


def test_train_config_and_cli_carry_the_motion():
    assert TrainConfig().motion == "kinematic"
    assert TrainConfig(motion="mjx:wheel_torque_max=0.5").motion == "mjx:wheel_torque_max=0.5"
    with pytest.raises(ValueError, match="unknown motion model 'car'"):
        TrainConfig(motion="car")
    # run.json of runs from before the motion models: kinematic.
    saved = dataclasses.asdict(TrainConfig())
    del saved["motion"]
    assert train_config_from_dict(saved).motion == "kinematic"
    assert train_config_from_dict(dataclasses.asdict(TrainConfig(motion="mjx"))).motion == "mjx"
    assert build_run(TrainArgs(motion="mjx"))[0].motion == "mjx"
    assert build_run(TrainArgs())[0].motion == "kinematic"


def test_training_and_evaluation_build_their_envs_with_the_motion(monkeypatch):
    from advisor_jax.training import train

    made = []
    real = envs.make_env

    def spy(arena, **kw):
        made.append(kw.get("motion"))
        return real(arena, **kw)

    monkeypatch.setattr(envs, "make_env", spy)
    train.make_train(TrainConfig(motion="mjx", episodes=2))
    evaluate_module.population_evaluator("validation", 2, HIDDEN, 20, motion="mjx")
    assert made == ["mjx", "mjx"]


def test_a_run_directory_reports_its_motion(tmp_path):
    config = dataclasses.asdict(TrainConfig(motion="mjx:omega_max=4"))
    agents = [{"index": i, "seed": i} for i in range(4)]
    run = {"config": config, "agents": agents, "status": "finished"}
    (tmp_path / "run.json").write_text(json.dumps(run))
    assert policy_motion(str(tmp_path)) == "mjx:omega_max=4"
    assert policy_motion(f"{tmp_path}:3") == "mjx:omega_max=4"
    assert policy_motion("advisor") is None


@pytest.fixture(scope="module")
def mjx_export(tmp_path_factory):
    """An actor exported as one trained in the mjx physical arena."""
    env = envs.make_env("physical", motion="mjx")
    params = init_actor(make_actor(HIDDEN), jax.random.PRNGKey(0))
    out = tmp_path_factory.mktemp("export")
    obs = np.random.default_rng(0).uniform(0, 1, (20, 20)).astype(np.float32)
    export_policy(
        params, out, actor_hidden=HIDDEN, env_meta=env.metadata(), config_meta={}, golden_obs=obs
    )
    return out


def test_the_export_records_the_motion_and_the_runner_reads_it(mjx_export):
    policy = load_policy(mjx_export)
    assert policy.env["motion"] == "mjx" and policy.omega_max == 5.0
    assert policy_motion(str(mjx_export)) == "mjx"


def test_the_runner_refuses_a_motion_model_it_does_not_know(mjx_export, tmp_path):
    meta = json.loads((mjx_export / "policy.json").read_text())
    meta["env"]["motion"] = "ackermann"
    meta["config_hash"] = config_hash(meta["config"], meta["env"])  # a consistent file
    meta["metadata_sha256"] = metadata_sha256(meta)
    for name in ("policy.npz", "golden.npz"):
        (tmp_path / name).write_bytes((mjx_export / name).read_bytes())
    (tmp_path / "policy.json").write_text(json.dumps(meta))
    with pytest.raises(PolicyError, match="motion model this runner does not know"):
        load_policy(tmp_path)


class _Built(Exception):
    """Raised by the spy instead of compiling the evaluation."""


def test_evaluate_uses_the_model_the_policy_was_trained_with(mjx_export, monkeypatch, capsys):
    def spy(env, apply, episodes):
        raise _Built(env.config.motion_setting, env.config.omega_max)

    monkeypatch.setattr(evaluate_module, "make_evaluate", spy)
    with pytest.raises(_Built) as built:
        cli.evaluate(policy=str(mjx_export), arena="physical", episodes=2)
    assert built.value.args == ("mjx", 5.0)
    with pytest.raises(_Built) as built:
        cli.evaluate(policy="advisor", arena="physical", episodes=2)
    assert built.value.args == ("kinematic", 3.0)
    # Out of its training conditions on request, with a warning.
    with pytest.raises(_Built) as built:
        cli.evaluate(policy=str(mjx_export), arena="physical", episodes=2, motion="mjx:substeps=10")
    assert built.value.args == ("mjx:substeps=10", 5.0)
    assert "trained with motion 'mjx'" in " ".join(capsys.readouterr().err.split())  # any wrap
