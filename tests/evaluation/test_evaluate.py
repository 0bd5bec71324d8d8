"""Batched deterministic evaluation (evaluation/evaluate.py): metrics by hand, the first
episode of each env kept, vmap over policy parameters equal to a per-step loop."""

from __future__ import annotations

import math

import jax
import jax.numpy as jnp
import numpy as np
import pytest

import envs
from advisor_jax.evaluation.evaluate import (
    EvalMetrics,
    collision_speed_sd,
    make_evaluate,
    mean_collision_speed,
    success_rate,
    summary,
    timeout_rate,
)
from envs.navigation import COLLISION, GOAL, TIMEOUT

H = 12  # a short h_max keeps the evaluation compile small


def test_metric_helpers_hand_values():
    m = EvalMetrics(
        outcome=jnp.array([GOAL, COLLISION, TIMEOUT, GOAL, COLLISION]),
        length=jnp.array([10, 20, 300, 30, 40]),
        episode_return=jnp.zeros(5),
        collision_speed=jnp.array([9.0, 0.4, 9.0, 9.0, 0.6]),
    )
    np.testing.assert_allclose([m.success_rate, m.collision_rate, m.timeout_rate], [0.4, 0.4, 0.2])
    np.testing.assert_allclose(m.mean_collision_speed, 0.5)  # only collision episodes count
    np.testing.assert_allclose(collision_speed_sd(m), 0.1, rtol=1e-5)  # 0.4, 0.6 about 0.5
    assert summary(m)["collision_speed_sd"] == pytest.approx(0.1, rel=1e-5)
    assert summary(m.replace(outcome=jnp.full(5, GOAL)))["collision_speed_sd"] is None
    assert math.isnan(float(collision_speed_sd(m.replace(outcome=jnp.full(5, GOAL)), math.nan)))
    none = m.replace(outcome=jnp.array([GOAL, TIMEOUT, GOAL, GOAL, TIMEOUT]))
    assert (
        float(mean_collision_speed(none)) == 0.0 and summary(none)["mean_collision_speed"] is None
    )
    assert math.isnan(float(mean_collision_speed(none, empty=float("nan"))))
    grad = jax.grad(lambda s: mean_collision_speed(none.replace(collision_speed=s)))(jnp.ones(5))
    assert np.all(np.isfinite(grad))


@pytest.fixture(scope="module")
def short_env():
    return envs.make_env("training", max_episode_steps=H)


def test_evaluate_keeps_the_first_episode_and_vmaps_over_params(short_env):
    """Policy (V, ω) = (p, p / 2): p = 0 never moves (all timeouts at H, return 0); p = 1
    drives circles. vmap over p equals a plain per-step reference loop."""
    episodes = 16

    def policy(p, obs):
        return jnp.stack([p, 0.5 * p])

    evaluate_fn = make_evaluate(short_env, policy, episodes)
    key = jax.random.PRNGKey(4)
    both = jax.jit(jax.vmap(evaluate_fn, in_axes=(0, None)))(jnp.array([0.0, 1.0]), key)
    assert both.outcome.shape == (2, episodes)

    still = jax.tree_util.tree_map(lambda x: x[0], both)
    np.testing.assert_array_equal(still.outcome, TIMEOUT)
    np.testing.assert_array_equal(still.length, H)
    np.testing.assert_allclose(still.episode_return, 0.0, atol=1e-5)
    assert float(success_rate(still)) == 0.0 and float(timeout_rate(still)) == 1.0

    # Reference: step all envs H times, record each env's first finished episode by hand.
    states = jax.jit(jax.vmap(short_env.reset))(jax.random.split(key, episodes))
    step = jax.jit(jax.vmap(short_env.step))
    first = {}
    for _ in range(H):
        states = step(states, jnp.tile(jnp.array([1.0, 0.5]), (episodes, 1)))
        for i in np.flatnonzero(np.asarray(states.done)):
            first.setdefault(i, (int(states.outcome[i]), int(states.episode_length[i])))
    moving = jax.tree_util.tree_map(lambda x: x[1], both)
    assert sorted(first) == list(range(episodes))
    np.testing.assert_array_equal(moving.outcome, [first[i][0] for i in range(episodes)])
    np.testing.assert_array_equal(moving.length, [first[i][1] for i in range(episodes)])


def test_make_evaluate_rejects_bad_episode_counts(short_env):
    with pytest.raises(ValueError, match="episodes"):
        make_evaluate(short_env, lambda p, o: o[:2], 0)


def test_the_advisor_is_evaluated_through_its_interface_on_the_same_episodes(short_env):
    """The advisor alone (``advisor_evaluator``) vmaps over quality knobs; at zero knobs it is
    the plain rule on the same episodes (its own draws leave the starts as they are)."""
    from advisor_jax.agent.advisor import advisor_action, arena_advisor
    from advisor_jax.agent.advisor_quality import AdvisorQuality
    from advisor_jax.evaluation.evaluate import advisor_evaluator
    from advisor_jax.training.advisor_source import resolve_advisor

    episodes, key = 24, jax.random.PRNGKey(9)
    advisor = resolve_advisor("rule", short_env)
    qualities = [AdvisorQuality(), AdvisorQuality(advisor_random=1.0)]
    stacked = jax.tree.map(lambda *x: jnp.asarray(x, jnp.float32), *qualities)
    both = advisor_evaluator(short_env, advisor, episodes)(stacked, key)
    plain = jax.jit(make_evaluate(short_env, lambda p, o: advisor_action(o, p), episodes))(
        arena_advisor(short_env), key
    )
    np.testing.assert_array_equal(both.outcome[0], plain.outcome)
    np.testing.assert_array_equal(both.length[0], plain.length)
    np.testing.assert_allclose(both.episode_return[0], plain.episode_return, atol=1e-4)
    assert not np.array_equal(both.length[1], plain.length)  # acting at random differs
