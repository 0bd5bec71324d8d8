"""Export + numpy runner in the loop of the simulated physical arena.

A small MLP is cloned from the advisor (so episodes reach the goal as well as collide),
exported, loaded by the numpy runner, and driven from simulated RPLIDAR scans and tracked
poses. Its outcomes must match the JAX evaluation of the same weights on the same episodes.
"""

from __future__ import annotations

import jax
import jax.numpy as jnp
import optax
import pytest

import envs
from advisor_jax.agent.advisor import advisor_action, arena_advisor
from advisor_jax.agent.networks import init_actor, make_actor
from advisor_jax.deploy.export import export_policy
from advisor_jax.evaluation.closed_loop import run_closed_loop
from advisor_jax.evaluation.evaluate import rollout_observations
from advisor_jax.runner.policy import load_policy

HIDDEN = (32, 32)


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
