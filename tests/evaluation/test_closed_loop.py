"""Export + numpy runner in the loop of the simulated physical arena.

A small MLP is cloned from the advisor (so episodes reach the goal as well as collide),
exported, loaded by the numpy runner, and driven from simulated RPLIDAR scans and tracked
poses. Its outcomes must match the JAX evaluation of the same weights on the same episodes.
"""

from __future__ import annotations

import json
import os
import subprocess
import sys
from pathlib import Path

import jax
import jax.numpy as jnp
import numpy as np
import optax
import pytest

import envs
from advisor_jax.agent.advisor import advisor_action, arena_advisor
from advisor_jax.agent.networks import init_actor, make_actor
from advisor_jax.cli import car
from advisor_jax.deploy.export import actor_params_from_policy, export_policy
from advisor_jax.evaluation.closed_loop import run_closed_loop
from advisor_jax.evaluation.evaluate import rollout_observations
from advisor_jax.runner.policy import load_policy

HIDDEN = (32, 32)
ROOT = Path(__file__).resolve().parents[2]


def clone_advisor(env, key, steps=600):
    """Behaviour cloning of the advisor: observations from advisor rollouts, MSE fit."""
    advisor = lambda p, o: advisor_action(o, p)  # noqa: E731
    obs = rollout_observations(env, advisor, arena_advisor(env), key, n_envs=64, steps=60)
    targets = jax.vmap(advisor_action, in_axes=(0, None))(jnp.asarray(obs), arena_advisor(env))
    actor = make_actor(HIDDEN)
    params = init_actor(actor, key)
    opt = optax.adam(3e-3)

    def loss(p):
        return jnp.mean(jnp.sum(jnp.square(actor.apply(p, obs) - targets), -1))

    @jax.jit
    def fit(params):
        def body(carry, _):
            p, s = carry
            g = jax.grad(loss)(p)
            u, s = opt.update(g, s, p)
            return (optax.apply_updates(p, u), s), None

        (params, _), _ = jax.lax.scan(body, (params, opt.init(params)), None, length=steps)
        return params

    return fit(params), obs


@pytest.fixture(scope="module")
def exported(tmp_path_factory):
    env = envs.make_env("physical")
    params, obs = clone_advisor(env, jax.random.PRNGKey(0))
    out = tmp_path_factory.mktemp("policy")
    export_policy(
        params,
        out,
        actor_hidden=HIDDEN,
        env_meta=env.metadata(),
        config_meta={"agent": "advisor-clone"},
        golden_obs=obs[::10],
    )
    return load_policy(out)


def test_runner_drives_like_the_jax_actor(exported):
    result = run_closed_loop(exported, episodes=10, key=jax.random.PRNGKey(7))
    assert result.stops == 0, "the watchdog must not fire on fresh simulated data"
    assert envs.GOAL in result.jax_outcomes, "the cloned advisor should reach some goals"
    assert result.agreement >= 0.9
    assert abs(result.runner_success - result.jax_success) <= 0.1


# The car without a car (issue 38) -------------------------------------------------------


@pytest.fixture(scope="module")
def jax_episode(exported):
    """seed -> (outcome, length) of the JAX actor's episode from ``reset(PRNGKey(seed))``,
    reset, step and actor compiled once for every seed (an eager reset ran op by op)."""
    env = envs.make_env("physical")
    params, hidden = actor_params_from_policy(exported)
    act = jax.jit(make_actor(hidden).apply)
    reset, step = jax.jit(env.reset), jax.jit(env.step)

    def episode(seed: int) -> tuple[int, int]:
        state = reset(jax.random.PRNGKey(seed))
        for _ in range(env.max_episode_steps):
            state = step(state, act(params, state.obs))
            if bool(state.done):
                return int(state.outcome), int(state.episode_length)
        raise AssertionError("an episode ends within h_max")

    return episode


def test_sim_mode_drives_the_runner_loop_like_the_jax_actor(
    exported, jax_episode, tmp_path, capsys
):
    """advisor-jax-car POLICY --sim: the runner's real loop (watchdog, drive, log) against
    the simulated arena ends each episode as the JAX evaluation of the same start does, one
    cycle later (the controller sees the goal or obstacle on the next scan), and its log
    replays bit for bit."""
    ends = {envs.GOAL: "goal_reached", envs.COLLISION: "collision", envs.TIMEOUT: "max_cycles"}
    seen = set()
    for seed in range(4):
        log = tmp_path / f"sim{seed}.jsonl"
        args = [exported.directory, "--sim", "--seed", str(seed), "--log", str(log)]
        assert car.main(args) == 0
        footer = json.loads(log.read_text().splitlines()[-1])
        outcome, length = jax_episode(seed)
        seen.add(outcome)
        assert footer["end"] == ends[outcome], (seed, footer, outcome, length)
        cycles = 150 if outcome == envs.TIMEOUT else length + 1
        assert footer["cycles"] == cycles and footer["stops"].get("no_scan") is None
        assert car.main(["--replay", str(log), exported.directory]) == 0
    assert envs.GOAL in seen
    assert "driving the simulated car" in capsys.readouterr().err


def test_a_sonar_export_is_refused_in_one_line(tmp_path, capsys):
    """A `training`-arena (sonar) export has no lidar to drive from: --sim and the closed
    loop say so in one line (the closed loop raised a bare ValueError traceback)."""
    env = envs.make_env("training")
    params = init_actor(make_actor(HIDDEN), jax.random.PRNGKey(1))
    out = tmp_path / "sonar"
    obs = np.asarray(jax.jit(env.reset)(jax.random.PRNGKey(0)).obs)[None]
    export_policy(params, out, actor_hidden=HIDDEN, env_meta=env.metadata(),
                  config_meta={"agent": "random"}, golden_obs=obs)  # fmt: skip
    assert car.main([str(out), "--sim"]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "trained in the 'training' arena" in err[0], err
    script = subprocess.run(
        [sys.executable, "experiments/closed_loop.py", str(out), "--episodes", "2",
         "--out", str(tmp_path / "results")],
        capture_output=True, text=True, cwd=ROOT, timeout=600,
        env={**os.environ, "PYTHONPATH": str(ROOT)},  # this checkout's package
    )  # fmt: skip
    lines = script.stderr.strip().splitlines()
    assert script.returncode != 0 and "Traceback" not in script.stderr
    assert "trained in the 'training' arena" in lines[-1]


def test_the_shipped_sample_log_replays():
    """docs/examples/sim_drive.jsonl (advisor-jax-car results/policy_physical_atd3_afdp
    --sim) replays against the shipped export, as the README says."""
    log = ROOT / "docs/examples/sim_drive.jsonl"
    assert car.main(["--replay", str(log), str(ROOT / "results/policy_physical_atd3_afdp")]) == 0
