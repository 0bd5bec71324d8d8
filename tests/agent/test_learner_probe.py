"""Probe problems with known answers, learned by make_learner's steps in a jitted loop.

* Bandit (one step, terminal = 1): r = -||a - a*|| with a* = (0.7, -0.4) inside the box,
  one fixed observation. Q*(s, a) = r(a), so Q*(s, a*) = 0 and the optimal action is a*.
  The cone, unlike -||a - a*||², has a sharp peak: a critic within ±0.05 of Q* then has its
  maximum within a few hundredths of a*, where the flat top of the quadratic would allow
  ±0.2 for the same critic error.
* Two steps: s0 → s1 with r = 0 (not terminal), s1 → s0 with r = 1 (terminal). With
  γ = 0.9, Q(s0, ·) = γ·1 = 0.9 (bootstrapping) and Q(s1, ·) = 1 (terminal masking; if
  the terminal flag were ignored, Q(s1) = 1/(1 - γ²) ≈ 5.3 and Q(s0) ≈ 4.7).

The loop runs ``Learner.update``, the one update step training runs (sample a batch, critic
step, actor step every cfg.delay-th update), inside one lax.scan, after WARMUP critic-only
updates: an actor trained on the untrained critic can saturate its sigmoid/tanh heads at a
corner of the box and stay there.
"""

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from advisor_jax.agent.config import HParams
from advisor_jax.agent.replay_buffer import Transition, replay_add, replay_init, replay_sample

A_STAR = np.array([0.7, -0.4], np.float32)
ADVISOR = np.array([0.2, 0.5], np.float32)  # a poor advisor: AfP must not pull π to it
UPDATES = 1000
WARMUP = 200
CAPACITY = 512
HP = jax.tree.map(np.float32, HParams(lr_actor=3e-3, lr_critic=3e-3, beta=0.25, gamma=0.9, tau=0.1))


def _probe_loop(agent):
    cfg, learner = agent.cfg, agent.learner

    def run(state, replay, key, hp):
        def critic_only(state, key):
            key_sample, key_critic = jax.random.split(key)
            batch = replay_sample(replay, key_sample, cfg.batch_size)
            state, metrics = learner.critic_step(state, batch, key_critic, hp)
            return state, metrics["loss/critic"]

        def update(state, inputs):
            t, key = inputs
            key_sample, key_critic = jax.random.split(key)
            state, metrics, _ = learner.update(
                state, learner.sample(replay, key_sample), key_critic, hp, t
            )
            return state, metrics["loss/critic"]

        keys = jax.random.split(key, UPDATES)
        state, warm = jax.lax.scan(critic_only, state, keys[:WARMUP])
        state, rest = jax.lax.scan(update, state, (jnp.arange(WARMUP, UPDATES), keys[WARMUP:]))
        return state, jnp.concatenate([warm, rest])

    return jax.jit(run)


@pytest.fixture(scope="module")
def probe_loop(agents):
    """name -> jitted loop; one compile per agent type, shared by both probes."""
    loops = {}

    def get(name):
        if name not in loops:
            loops[name] = _probe_loop(agents[name])
        return loops[name]

    return get


def _buffer(obs, action, reward, next_obs, terminal, advisor):
    return replay_add(
        replay_init(CAPACITY),
        Transition(
            obs=obs,
            action=action,
            advisor_action=advisor,
            reward=reward,
            next_obs=next_obs,
            terminal=terminal,
        ),
    )


def _random_actions(rng, n):
    return rng.uniform([0.0, -1.0], [1.0, 1.0], (n, 2)).astype(np.float32)


def _bandit(rng):
    obs = np.tile(rng.uniform(0.0, 1.0, (1, 20)).astype(np.float32), (CAPACITY, 1))
    action = _random_actions(rng, CAPACITY)
    reward = -np.linalg.norm(action - A_STAR, axis=-1)
    ones = np.ones(CAPACITY, np.float32)
    return obs[:1], _buffer(obs, action, reward, obs, ones, np.tile(ADVISOR, (CAPACITY, 1)))


def _two_step(rng):
    half = CAPACITY // 2
    s0, s1 = np.eye(20, dtype=np.float32)[:2]
    obs = np.concatenate([np.tile(s0, (half, 1)), np.tile(s1, (half, 1))])
    next_obs = obs[::-1].copy()  # s0 → s1 and s1 → s0
    reward = np.concatenate([np.zeros(half), np.ones(half)]).astype(np.float32)
    action = _random_actions(rng, CAPACITY)
    return (s0, s1), _buffer(obs, action, reward, next_obs, reward.copy(), action)


@pytest.mark.parametrize("name", ["ddpg", "addpg", "atd3"])
def test_bandit_probe(agents, probe_loop, ref, name):
    agent = agents[name]
    obs, replay = _bandit(np.random.default_rng(0))
    state = agent.init(jax.random.key(1))
    state, losses = probe_loop(name)(state, replay, jax.random.key(2), HP)
    assert float(losses[-50:].mean()) < 0.1 * float(losses[:50].mean())

    # The critic knows Q*: 0 at a*, and the right value far from it (min over critics).
    probe = np.stack([A_STAR, [0.0, 1.0], [1.0, -1.0], [0.5, 0.0]]).astype(np.float32)
    q_true = -np.linalg.norm(probe - A_STAR, axis=-1)  # 0, -1.565, -0.671, -0.447
    q = ref.critics(state.critic, np.tile(obs, (4, 1)), probe).min(axis=0)
    np.testing.assert_allclose(q, q_true, atol=0.15)
    # The actor found a*.
    action = ref.actor(state.actor, obs)[0]
    assert np.linalg.norm(action - A_STAR) < 0.1, action


@pytest.mark.parametrize("name", ["ddpg", "atd3"])
def test_two_step_bootstrap_and_terminal(agents, probe_loop, ref, name):
    agent = agents[name]
    rng = np.random.default_rng(3)
    (s0, s1), replay = _two_step(rng)
    state = agent.init(jax.random.key(4))
    state, _ = probe_loop(name)(state, replay, jax.random.key(5), HP)
    actions = _random_actions(rng, 32)
    q0 = ref.critics(state.critic, np.tile(s0, (32, 1)), actions)  # [n_critics, 32]
    q1 = ref.critics(state.critic, np.tile(s1, (32, 1)), actions)
    np.testing.assert_allclose(q0, HP.gamma * 1.0, atol=0.05)
    np.testing.assert_allclose(q1, 1.0, atol=0.05)
