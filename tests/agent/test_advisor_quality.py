"""The advisor's quality knobs (``agent/advisor_quality.py``): at zero the advisor exactly,
each knob what it says, vmappable over knobs, and a delay that restarts with each episode."""

from __future__ import annotations

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from advisor_jax.agent.advisor import AdvisorParams, advisor_action
from advisor_jax.agent.advisor_quality import (
    MAX_DELAY,
    AdvisorQuality,
    advisor_view,
    make_acting,
    memory_init,
    restart,
)
from advisor_jax.agent.settings import replace_flat, validate
from tests.agent.test_advisors import _observations

PARAMS = AdvisorParams()


def rule(params, obs):
    return advisor_action(obs, params)


ACT = jax.jit(make_acting(rule, PARAMS))


@jax.jit
def act_and_rule(quality, memory, obs, key):
    """The advisor under ``quality`` and the bare rule, in one program: XLA may lower the
    rule's dot products differently in different programs (a last-bit difference that has
    nothing to do with the knobs), never within one."""
    action, memory = make_acting(rule, PARAMS)(quality, memory, obs, key)
    return action, memory, jax.vmap(rule, in_axes=(None, 0))(PARAMS, obs)


def _bits(x) -> np.ndarray:
    return np.asarray(x, np.float32).view(np.uint32)


def _play(quality, steps: int, n_envs: int = 32, done_at=()):
    """(observations, the advisor's actions, the bare rule's) over ``steps`` steps of random
    observations; ``done_at``: steps after which every episode ends."""
    memory = memory_init(n_envs)
    obs = _observations(steps * n_envs, seed=3).reshape(steps, n_envs, 20)
    out, bare = [], []
    for t in range(steps):
        key = jnp.array([0, t], jnp.uint32)
        action, memory, plain = act_and_rule(quality, memory, jnp.asarray(obs[t]), key)
        out.append(np.asarray(action))
        bare.append(np.asarray(plain))
        memory = restart(memory, jnp.full(n_envs, t in done_at))
    return obs, np.stack(out), np.stack(bare)


def test_knobs_at_zero_are_the_advisor_bit_for_bit():
    _, actions, bare = _play(AdvisorQuality(), steps=6, done_at=(2,))
    np.testing.assert_array_equal(_bits(actions), _bits(bare))


def test_delay_acts_on_what_it_saw_and_restarts_with_the_episode():
    _, actions, bare = _play(AdvisorQuality(advisor_delay=3.0), steps=9, done_at=(4,))
    for t in range(9):
        start = 0 if t <= 4 else 5  # the second episode starts at step 5
        seen = max(start, t - 3)  # nothing older than the episode's first step
        np.testing.assert_array_equal(actions[t], bare[seen], err_msg=f"step {t}")


def test_the_view_blinds_a_sector_ahead_and_shortens_the_range():
    obs = jnp.asarray(np.r_[np.linspace(0.2, 0.95, 16), [0.3, 2.0, 0, 0]].astype(np.float32))
    # Sonar directions 90, 50, 30, 10, -10, -30, -50, -90, -90, ... (contract/spec.py).
    blind = np.asarray(advisor_view(obs, AdvisorQuality(advisor_blind=61.0)))
    np.testing.assert_array_equal(blind[[2, 3, 4, 5]], 1.0)  # |direction| < 30.5°
    np.testing.assert_array_equal(np.delete(blind, [2, 3, 4, 5]), np.delete(obs, [2, 3, 4, 5]))
    near = np.asarray(advisor_view(obs, AdvisorQuality(advisor_range=0.5)))
    far = np.asarray(obs[:16]) >= 0.5
    np.testing.assert_array_equal(near[:16][far], 1.0)
    np.testing.assert_array_equal(near[:16][~far], np.asarray(obs[:16])[~far])
    np.testing.assert_array_equal(near[16:], np.asarray(obs[16:]))


def test_an_obstacle_in_the_blind_sector_is_not_avoided():
    ahead = np.zeros(20, np.float32)
    ahead[:16], ahead[3], ahead[4], ahead[17] = 1.0, 0.25, 0.25, 2.0  # wall ahead, goal ahead
    seeing, _ = ACT(
        AdvisorQuality(), memory_init(1), jnp.asarray(ahead[None]), jnp.zeros(2, jnp.uint32)
    )
    blind, _ = ACT(AdvisorQuality(advisor_blind=30.0), memory_init(1), jnp.asarray(ahead[None]),
                   jnp.zeros(2, jnp.uint32))  # fmt: skip
    assert float(seeing[0, 0]) < 0.5  # Braitenberg: it slows down
    np.testing.assert_allclose(np.asarray(blind[0]), [1.0 - np.exp(-10.0), 0.0], atol=1e-6)


def test_noise_and_random_actions_in_the_box_at_their_rates():
    n = 4000
    obs = jnp.asarray(_observations(n, seed=5))
    quality = AdvisorQuality(advisor_random=0.3)
    action, _, clean = act_and_rule(quality, memory_init(n), obs, jnp.array([0, 7], jnp.uint32))
    replaced = np.any(np.asarray(action) != np.asarray(clean), axis=-1)
    assert abs(replaced.mean() - 0.3) < 0.03  # 4.1 standard errors
    quality = AdvisorQuality(advisor_noise=0.2)
    noisy, _, clean = act_and_rule(quality, memory_init(n), obs, jnp.array([0, 8], jnp.uint32))
    noisy, clean = np.asarray(noisy), np.asarray(clean)
    assert noisy[:, 0].min() >= 0.0 and noisy[:, 0].max() <= 1.0
    assert np.abs(noisy[:, 1]).max() <= 1.0
    free = np.abs(clean[:, 1]) < 0.5  # far from ω's bounds: the clip rarely bites
    spread = np.std(noisy[free, 1] - clean[free, 1])
    assert 0.18 < spread < 0.21, spread  # σ = 0.2


def test_a_population_of_knobs_is_one_vmap():
    qualities = [AdvisorQuality(), AdvisorQuality(advisor_noise=0.3),
                 AdvisorQuality(advisor_delay=2.0, advisor_range=0.4)]  # fmt: skip
    stacked = jax.tree.map(lambda *x: jnp.stack([jnp.float32(v) for v in x]), *qualities)
    obs = jnp.asarray(_observations(16))
    key = jnp.array([0, 11], jnp.uint32)
    together, _ = jax.vmap(ACT, in_axes=(0, None, None, None))(stacked, memory_init(16), obs, key)
    for i, q in enumerate(qualities):
        alone, _ = ACT(q, memory_init(16), obs, key)  # the same draws; a vmapped dot may
        np.testing.assert_allclose(together[i], alone, atol=1e-6)  # sum in another order


@pytest.mark.parametrize(
    "name, value, message",
    [
        ("advisor_delay", 1.5, "advisor_delay=1.5 is not one of the whole numbers in \\[0, 10\\]"),
        ("advisor_delay", MAX_DELAY + 1, "advisor_delay=11 is not one of the whole numbers"),
        ("advisor_random", 1.2, "advisor_random=1.2 is outside \\[0, 1\\]"),
        ("advisor_range", 0.0, "advisor_range=0 is outside \\(0, 1\\]"),
        ("advisor_noise", -0.1, "advisor_noise=-0.1 is outside"),
    ],
)
def test_knobs_out_of_range_are_named(name, value, message):
    with pytest.raises(ValueError, match=message):
        validate(replace_flat(AdvisorQuality(), **{name: value}))
