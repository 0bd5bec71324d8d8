"""The twin critics' inputs per critic or shared (networks.apply_critics, ``inputs_per_critic``,
chosen by ``training.program.twin_inputs_per_critic``).

Both layouts compute the same function: Q-values, parameter gradients and ∇_a Q of a
population of twin critics agree to fp32 rounding (close in bf16). The per-critic layout
leaves no merged ``obs @ [K_1, K_2]`` GEMM in the program. The default is per critic on a
GPU, in both precisions; on a CPU it is the shared layout, bit for bit, so fixed-seed CPU
runs keep their trajectories.
"""

from __future__ import annotations

import re
from types import SimpleNamespace

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from advisor_jax.agent import networks
from advisor_jax.contract import spec
from advisor_jax.training.program import twin_inputs_per_critic
from tests.agent.conftest import SMALL
from tests.compare import max_relative_difference

CFG = SimpleNamespace(
    critic_state_hidden=SMALL["critic_state_hidden"], critic_hidden=SMALL["critic_hidden"]
)
N_CRITICS, N_AGENTS, BATCH = 2, 3, 32


def _population(precision: str):
    """Critic module, twin params of N_AGENTS agents and one batch per agent."""
    critic = networks.make_critic(CFG, precision)
    keys = jax.random.split(jax.random.key(0), N_AGENTS)
    params = jax.vmap(lambda k: networks.init_critics(critic, k, N_CRITICS))(keys)
    k_obs, k_act = jax.random.split(jax.random.key(1))
    obs = jax.random.normal(k_obs, (N_AGENTS, BATCH, spec.OBS_SIZE))
    action = jax.random.uniform(k_act, (N_AGENTS, BATCH, spec.ACTION_SIZE), minval=-1.0)
    return critic, params, obs, action


def _q_and_grads(critic, params, obs, action, inputs_per_critic):
    """Per agent: Q of both critics, and the gradients of a weighted sum of them w.r.t.
    the params and the action (the critic loss's and the actor step's pullbacks)."""
    w = jnp.linspace(-1.0, 1.0, N_CRITICS * BATCH).reshape(N_CRITICS, BATCH)

    def one_agent(p, o, a):
        def f(p, a):
            return jnp.sum(networks.apply_critics(critic.apply, p, o, a, inputs_per_critic) * w)

        q = networks.apply_critics(critic.apply, p, o, a, inputs_per_critic)
        return q, jax.grad(f, argnums=(0, 1))(p, a)

    return jax.jit(jax.vmap(one_agent))(params, obs, action)


@pytest.mark.parametrize(("precision", "bound"), [("fp32", 1e-5), ("bf16", 2e-2)])
def test_per_critic_inputs_compute_the_same_q_and_gradients(precision, bound):
    critic, params, obs, action = _population(precision)
    shared = _q_and_grads(critic, params, obs, action, inputs_per_critic=False)
    per_critic = _q_and_grads(critic, params, obs, action, inputs_per_critic=True)
    assert jax.tree.structure(shared) == jax.tree.structure(per_critic)
    # Bounds relative to each array's largest entry: the summation order of a GEMM (and
    # with it the last bits) differs between the layouts and between CPUs.
    assert max_relative_difference(shared, per_critic) < bound


def test_the_cpu_default_is_the_shared_layout_bit_for_bit():
    critic, params, obs, action = _population("fp32")
    default = _q_and_grads(critic, params, obs, action, twin_inputs_per_critic("cpu"))
    shared = _q_and_grads(critic, params, obs, action, inputs_per_critic=False)
    for x, y in zip(jax.tree.leaves(default), jax.tree.leaves(shared), strict=True):
        np.testing.assert_array_equal(np.asarray(x), np.asarray(y))


def _dot_output_widths(inputs_per_critic: bool) -> list[int]:
    """Last dimension of every dot in the optimized program of one agent's twin critics."""
    critic, params, obs, action = _population("fp32")
    one = jax.tree.map(lambda x: x[0], params)
    compiled = (
        jax.jit(
            lambda p: networks.apply_critics(critic.apply, p, obs[0], action[0], inputs_per_critic)
        )
        .lower(one)
        .compile()
    )
    shapes = re.findall(r"= f32\[([\d,]+)\][^ ]* dot\(", compiled.as_text())
    assert shapes, "no dot found in the compiled program"
    return [int(s.split(",")[-1]) for s in shapes]


def test_per_critic_inputs_leave_no_merged_twin_gemm():
    merged = N_CRITICS * CFG.critic_state_hidden  # obs @ [K_1, K_2]: both state layers at once
    assert merged in _dot_output_widths(inputs_per_critic=False)  # what the layout avoids
    assert merged not in _dot_output_widths(inputs_per_critic=True)


@pytest.mark.parametrize(("backend", "expected"), [("gpu", True), ("tpu", False), ("cpu", False)])
def test_the_default_layout_is_per_critic_only_on_a_gpu(backend, expected):
    assert twin_inputs_per_critic(backend) is expected
