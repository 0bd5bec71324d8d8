"""Shared fixtures of the learner tests: small agents, random batches, numpy references.

Compiling is the slow part on CPU, so every jitted function is built once per session,
test data is made with numpy, and the reference networks are numpy (float64) MLPs written
from the parameter layout of ``networks.py``; they are an independent check of the flax
forward pass and of ∇_a Q.
"""

from __future__ import annotations

from collections.abc import Callable
from types import SimpleNamespace
from typing import NamedTuple

import jax
import numpy as np
import pytest

from advisor_jax.agent.config import AgentConfig, HParams, parse_agent
from advisor_jax.agent.learner import Learner, make_learner
from advisor_jax.agent.replay_buffer import Transition

# Small networks: the rules do not depend on the widths.
SMALL = dict(
    actor_hidden=(32, 32),
    critic_state_hidden=64,
    critic_hidden=(64, 64),
    batch_size=64,
    buffer_size=512,
    policy_delay=2,
)
AGENTS = {
    "ddpg": "DDPG",
    "addpg": "ADDPG",
    "td3": "TD3",
    "atd3": "ATD3+AfDP",
}


class Agent(NamedTuple):
    cfg: AgentConfig
    learner: Learner
    init: Callable  # jitted Learner.init
    critic_step: Callable  # jitted Learner.critic_step
    actor_step: Callable  # jitted Learner.actor_step


@pytest.fixture(scope="session")
def agents() -> dict[str, Agent]:
    """Agent types at SMALL sizes; jax.jit compiles lazily, on a test's first call."""
    out = {}
    inits = {}
    for key, name in AGENTS.items():
        cfg = parse_agent(name, **SMALL)
        learner = make_learner(cfg)
        # init depends only on the sizes and n_critics, and compiling it is slow (one
        # truncated-normal sampler per layer): share one compiled init per n_critics.
        init = inits.setdefault(cfg.n_critics, jax.jit(learner.init))
        out[key] = Agent(
            cfg, learner, init, jax.jit(learner.critic_step), jax.jit(learner.actor_step)
        )
    return out


def _random_batch(seed: int, n: int) -> Transition:
    rng = np.random.default_rng(seed)
    low, high = np.array([0.0, -1.0]), np.array([1.0, 1.0])
    f32 = np.float32
    return Transition(
        obs=rng.uniform(0.0, 1.0, (n, 20)).astype(f32),
        action=rng.uniform(low, high, (n, 2)).astype(f32),
        advisor_action=rng.uniform(low, high, (n, 2)).astype(f32),
        reward=rng.normal(size=n).astype(f32),
        next_obs=rng.uniform(0.0, 1.0, (n, 20)).astype(f32),
        terminal=(rng.uniform(size=n) < 0.3).astype(f32),
    )


@pytest.fixture(scope="session")
def random_batch() -> Callable[[int, int], Transition]:
    """(seed, n) -> n random, valid transitions (numpy float32 leaves)."""
    return _random_batch


def assert_learner_steps_match(learner: Learner, plain: Agent, batch: Transition) -> None:
    """``learner`` (another arithmetic of ``plain``'s agent type) starts from the same state,
    and one critic step and one actor step land where ``plain``'s do, to fp32 rounding
    (Adam's first step is ±lr per entry, so an entry whose gradient is ~0 may step the other
    way)."""
    key = jax.random.PRNGKey(21)
    state = jax.jit(learner.init)(key)
    for x, y in zip(jax.tree.leaves(state), jax.tree.leaves(plain.init(key)), strict=True):
        np.testing.assert_array_equal(x, y)
    hp = jax.tree.map(np.float32, HParams(beta=0.05))
    k = jax.random.PRNGKey(23)
    (s_new, m_new), (s_plain, m_plain) = (
        jax.jit(learner.critic_step)(state, batch, k, hp),
        plain.critic_step(state, batch, k, hp),
    )
    (s_new, a_new), (s_plain, a_plain) = (
        jax.jit(learner.actor_step)(s_new, batch, hp),
        plain.actor_step(s_plain, batch, hp),
    )
    for name in ("loss/critic", "q/mean", "q/target", "loss/actor", "grad_norm/critic"):
        got, want = {**m_new, **a_new}[name], {**m_plain, **a_plain}[name]
        np.testing.assert_allclose(got, want, rtol=1e-5, err_msg=name)
    for field in ("critic", "actor", "target_critic", "target_actor"):
        for got, want, before in zip(
            *(jax.tree.leaves(getattr(s, field)) for s in (s_new, s_plain, state)), strict=True
        ):
            same = np.isclose(got - before, want - before, rtol=1e-4, atol=1e-9)
            assert same.mean() > 0.99, field


# Numpy reference networks ----------------------------------------------------------------


def _kernel(layer) -> np.ndarray:
    """A layer's [in, out] kernel; the critic's join layer keeps its state and action row
    blocks apart (``networks.JoinDense``): stacked, they are the concatenated layer's."""
    k = layer["kernel"]
    if isinstance(k, dict):
        k = np.concatenate([np.asarray(k["state"]), np.asarray(k["action"])], axis=0)
    return np.asarray(k, np.float64)


def _layers(params, names):
    p = params["params"]
    return [(_kernel(p[n]), np.asarray(p[n]["bias"], np.float64)) for n in names]


def _hidden_names(params) -> list[str]:
    return sorted(
        (n for n in params["params"] if n.startswith("hidden_")), key=lambda n: int(n[7:])
    )


def np_actor(params, obs) -> np.ndarray:
    """π(s): ReLU hidden layers, sigmoid head for V and tanh head for ω. [n, 2]."""
    x = np.asarray(obs, np.float64)
    for kernel, bias in _layers(params, _hidden_names(params)):
        x = np.maximum(x @ kernel + bias, 0.0)
    ((kernel, bias),) = _layers(params, ["head"])
    logits = x @ kernel + bias
    return np.stack([1.0 / (1.0 + np.exp(-logits[:, 0])), np.tanh(logits[:, 1])], axis=-1)


def np_critic(params, obs, action) -> tuple[np.ndarray, np.ndarray]:
    """One critic (no leading critic axis): (Q [n], ∇_a Q [n, 2]) by hand-written backprop."""
    ((kernel, bias),) = _layers(params, ["state"])
    h = np.maximum(np.asarray(obs, np.float64) @ kernel + bias, 0.0)
    x = np.concatenate([h, np.asarray(action, np.float64)], axis=-1)
    layers = _layers(params, _hidden_names(params))
    pre = []
    for kernel, bias in layers:
        z = x @ kernel + bias
        pre.append(z)
        x = np.maximum(z, 0.0)
    ((kernel, bias),) = _layers(params, ["q"])
    q = (x @ kernel + bias)[:, 0]
    grad = np.broadcast_to(kernel[:, 0], x.shape)  # dQ/d(last hidden activation)
    for (kernel, _), z in zip(reversed(layers), reversed(pre), strict=True):
        grad = (grad * (z > 0)) @ kernel.T
    return q, grad[:, -2:]  # the action is the last 2 inputs of the first hidden layer


def np_critics(params, obs, action) -> np.ndarray:
    """Q of every stacked critic: [n_critics, n]."""
    n_critics = jax.tree.leaves(params)[0].shape[0]
    return np.stack(
        [
            np_critic(jax.tree.map(lambda x, k=k: x[k], params), obs, action)[0]
            for k in range(n_critics)
        ]
    )


@pytest.fixture(scope="session")
def ref() -> SimpleNamespace:
    """Numpy reference networks: actor(params, obs), critic(params_one, obs, a) -> (q, dq/da),
    critics(stacked params, obs, a) -> [n_critics, n]."""
    return SimpleNamespace(actor=np_actor, critic=np_critic, critics=np_critics)
