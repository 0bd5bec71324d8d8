"""``envs.reward.return_bounds``: the interval of every discounted return of Eq. (8).

The learner's ``clip_q_target`` clips the critic's TD targets into it, so it must hold for
every state and policy: checked by hand for the paper's settings and on rollouts of random
actions, whose return-to-go from every step (terminal steps end it, timeouts and the end of
the rollout truncate it) must lie inside.
"""

from __future__ import annotations

import dataclasses

import jax
import numpy as np
import pytest

from envs.reward import return_bounds
from envs.state import EnvConfig

ARENA = "training"


def test_the_paper_settings_give_plus_minus_17_5():
    # c1 = c2 = 10; distance shaping 5 · 1 m/s · 0.05 s / (1 - 0.9) = 2.5; proximity 5 · 1 m.
    lo, hi = return_bounds(EnvConfig(), 0.9)
    assert (lo, hi) == pytest.approx((-17.5, 17.5))
    cfg = dataclasses.replace(EnvConfig(), goal_reward=4.0, collision_penalty=2.0, k_proximity=1.0)
    lo, hi = return_bounds(cfg, 0.5)  # shaping 5 · 0.05 / 0.5 + 1 = 1.5
    assert (lo, hi) == pytest.approx((-3.5, 5.5))
    # γ may be a traced, vmapped hyperparameter.
    lo, hi = jax.vmap(lambda g: return_bounds(EnvConfig(), g))(np.float32([0.0, 0.9]))
    np.testing.assert_allclose(hi, [15.25, 17.5], rtol=1e-6)
    np.testing.assert_allclose(lo, [-15.25, -17.5], rtol=1e-6)


def _returns_to_go(rewards, ends, gamma):
    """G_t = r_t + γ G_{t+1} within an episode; [T, B] arrays, ``ends`` marks last steps."""
    out, g = np.zeros_like(rewards), np.zeros(rewards.shape[1])
    for t in range(rewards.shape[0] - 1, -1, -1):
        g = rewards[t] + gamma * np.where(ends[t], 0.0, g)
        out[t] = g
    return out


def test_every_return_of_random_rollouts_lies_inside(sim):
    env_reset, env_step = sim.reset(ARENA), sim.step(ARENA)
    batch, steps = 64, 400
    state = env_reset(jax.random.split(jax.random.key(7), batch))
    rng = np.random.default_rng(0)
    rewards, ends = np.zeros((steps, batch)), np.zeros((steps, batch), bool)
    for t in range(steps):  # forward-biased random actions, held 5 steps: real progress
        if t % 5 == 0:
            action = rng.uniform([0.3, -1.0], [1.0, 1.0], (batch, 2)).astype(np.float32)
        state = env_step(state, action)
        rewards[t], ends[t] = np.asarray(state.reward), np.asarray(state.done)
    assert ends.sum() > batch  # episodes ended (goals and collisions among them)
    assert rewards.max() == pytest.approx(10.0) and rewards.min() == pytest.approx(-10.0)
    for gamma in (0.9, 0.99):
        returns = _returns_to_go(rewards, ends, gamma)
        lo, hi = return_bounds(sim.env(ARENA).config, gamma)
        assert lo <= returns.min() and returns.max() <= hi, gamma
        # Not vacuous: terminal rewards alone come within the shaping terms of it.
        assert returns.max() > 10.0 - 2.5 and returns.min() < -10.0 + 2.5, gamma
