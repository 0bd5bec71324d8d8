"""The hidden layers' bias inside the matmul (networks.affine, ``bias_in_gemm``).

Against a frozen copy of the plain layers (``nn.Dense``, ``x @ K_x + a @ K_a + b``: the
networks as they were before the bias row) and the float64 numpy references of conftest.py:
same parameter tree, shapes and initial values; forward, parameter gradients, ∇_a Q and the
actor's vjp equal to fp32 rounding; close in bf16; and no separate bias add or bias-gradient
reduction left in the program of a layer.
"""

from __future__ import annotations

from collections.abc import Sequence
from functools import partial
from types import SimpleNamespace
from typing import Any

import flax.linen as nn
import jax
import jax.numpy as jnp
import numpy as np
import pytest

from advisor_jax.agent import networks
from advisor_jax.agent.learner import make_learner
from advisor_jax.contract import spec
from tests.learn.conftest import SMALL, assert_learner_steps_match

he_init = nn.initializers.he_normal()
CFG = SimpleNamespace(
    critic_state_hidden=SMALL["critic_state_hidden"], critic_hidden=SMALL["critic_hidden"]
)
N_CRITICS = 2


# The plain layers, as networks.py computed them before the bias row ----------------------


class PlainActor(nn.Module):
    hidden: Sequence[int]
    dtype: Any = jnp.float32

    @nn.compact
    def __call__(self, obs):
        x = obs
        for i, width in enumerate(self.hidden):
            dense = nn.Dense(width, kernel_init=he_init, dtype=self.dtype, name=f"hidden_{i}")
            x = nn.relu(dense(x))
        logits = nn.Dense(spec.ACTION_SIZE, kernel_init=he_init, name="head")(x)
        return jnp.stack([nn.sigmoid(logits[..., 0]), jnp.tanh(logits[..., 1])], axis=-1)


class PlainJoinDense(nn.Module):
    features: int
    dtype: Any = jnp.float32

    @nn.compact
    def __call__(self, x, a):
        n, m = x.shape[-1], a.shape[-1]

        def init(key):
            whole = he_init(key, (n + m, self.features))
            return {"state": whole[:n], "action": whole[n:]}

        kernel = self.param("kernel", init)
        bias = self.param("bias", nn.initializers.zeros_init(), (self.features,))
        x, a, k_x, k_a, bias = (
            v.astype(self.dtype) for v in (x, a, kernel["state"], kernel["action"], bias)
        )
        return x @ k_x + a @ k_a + bias


class PlainCritic(nn.Module):
    state_hidden: int
    hidden: Sequence[int]
    dtype: Any = jnp.float32

    @nn.compact
    def __call__(self, obs, action):
        dense = partial(nn.Dense, kernel_init=he_init, dtype=self.dtype)
        x = nn.relu(dense(self.state_hidden, name="state")(obs))
        x = nn.relu(PlainJoinDense(self.hidden[0], dtype=self.dtype, name="hidden_0")(x, action))
        for i, width in enumerate(self.hidden[1:], start=1):
            x = nn.relu(dense(width, name=f"hidden_{i}")(x))
        return nn.Dense(1, kernel_init=he_init, name="q")(x)[..., 0]


def _nets(precision: str, bias_in_gemm: bool = True):
    """(actor, critic) of networks.py at SMALL sizes and their plain twins."""
    dtype = networks.PRECISIONS[precision]
    return (
        networks.make_actor(SMALL["actor_hidden"], precision, bias_in_gemm),
        networks.make_critic(CFG, precision, bias_in_gemm),
        PlainActor(tuple(SMALL["actor_hidden"]), dtype),
        PlainCritic(CFG.critic_state_hidden, tuple(CFG.critic_hidden), dtype),
    )


def _with_biases(params, seed: int):
    """Every leaf moved by noise, so that the biases are not the zeros of the init."""
    rng = np.random.default_rng(seed)
    return jax.tree.map(lambda x: x + 0.1 * rng.normal(size=x.shape).astype(np.float32), params)


@pytest.fixture(scope="module")
def params():
    actor, critic, _, _ = _nets("fp32")
    key_actor, key_critic = jax.random.split(jax.random.PRNGKey(7))
    return SimpleNamespace(
        actor=_with_biases(networks.init_actor(actor, key_actor), 1),
        critic=_with_biases(networks.init_critics(critic, key_critic, N_CRITICS), 2),
    )


def _shapes(tree):
    return jax.tree.map(lambda x: (x.shape, str(x.dtype)), tree)


def _assert_trees_close(a, b, rtol, scale_atol, err_msg=""):
    """Leafwise allclose with an atol relative to each leaf's scale (max |b|)."""
    for (path, x), y in zip(
        jax.tree_util.tree_leaves_with_path(a), jax.tree.leaves(b), strict=True
    ):
        x, y = np.asarray(x, np.float32), np.asarray(y, np.float32)
        atol = scale_atol * max(float(np.abs(y).max()), 1e-30)
        np.testing.assert_allclose(x, y, rtol=rtol, atol=atol, err_msg=f"{err_msg} {path}")


# Parameters ---------------------------------------------------------------------------------


@pytest.mark.parametrize("precision", ["fp32", "bf16"])
def test_parameter_tree_shapes_and_initial_values_are_the_plain_layers(precision):
    actor, critic, plain_actor, plain_critic = _nets(precision)
    key = jax.random.PRNGKey(3)
    pairs = [
        (networks.init_actor(actor, key), networks.init_actor(plain_actor, key)),
        (
            networks.init_critics(critic, key, N_CRITICS),
            networks.init_critics(plain_critic, key, N_CRITICS),
        ),
    ]
    for new, plain in pairs:
        assert jax.tree.structure(new) == jax.tree.structure(plain)
        assert _shapes(new) == _shapes(plain)
        for x, y in zip(jax.tree.leaves(new), jax.tree.leaves(plain), strict=True):
            np.testing.assert_array_equal(x, y)
    # the layout export and the numpy runner read, spelled out
    actor_p, critic_p = pairs[0][0]["params"], pairs[1][0]["params"]
    (a0, a1), (s, (c0, c1)) = SMALL["actor_hidden"], (CFG.critic_state_hidden, CFG.critic_hidden)
    assert _shapes(actor_p) == {
        "hidden_0": {"kernel": ((spec.OBS_SIZE, a0), "float32"), "bias": ((a0,), "float32")},
        "hidden_1": {"kernel": ((a0, a1), "float32"), "bias": ((a1,), "float32")},
        "head": {"kernel": ((a1, spec.ACTION_SIZE), "float32"), "bias": ((2,), "float32")},
    }
    k = N_CRITICS
    assert _shapes(critic_p) == {
        "state": {"kernel": ((k, spec.OBS_SIZE, s), "float32"), "bias": ((k, s), "float32")},
        "hidden_0": {
            "kernel": {
                "state": ((k, s, c0), "float32"),
                "action": ((k, spec.ACTION_SIZE, c0), "float32"),
            },
            "bias": ((k, c0), "float32"),
        },
        "hidden_1": {"kernel": ((k, c0, c1), "float32"), "bias": ((k, c1), "float32")},
        "q": {"kernel": ((k, c1, 1), "float32"), "bias": ((k, 1), "float32")},
    }


# fp32: the same function and gradients ------------------------------------------------------


def _critic_outputs(critic, params, obs, action):
    """Q of the stacked critics, d(Σ Q·w)/dθ and ∇_a Q (of each critic, summed over them)."""
    w = jnp.linspace(-0.5, 1.5, obs.shape[0])

    def loss(p, a):
        return jnp.sum(networks.apply_critics(critic, p, obs, a) * w)

    q = networks.apply_critics(critic, params, obs, action)
    g_params, g_action = jax.grad(loss, argnums=(0, 1))(params, action)
    dq_da = jax.vmap(
        jax.grad(lambda p, a: jnp.sum(critic.apply(p, obs, a)), argnums=1), in_axes=(0, None)
    )(params, action)
    return q, g_params, g_action, dq_da


def _actor_outputs(actor, params, obs):
    """π(s), and the vjp of π with a fixed cotangent: w.r.t. the parameters and the obs."""
    out, vjp = jax.vjp(actor.apply, params, obs)
    cot = jnp.stack(
        [jnp.linspace(-1.0, 1.0, obs.shape[0]), jnp.linspace(2.0, -1.0, obs.shape[0])], -1
    )
    return out, *vjp(cot)


def test_fp32_equals_the_plain_layers_to_rounding(params, random_batch, ref):
    actor, critic, plain_actor, plain_critic = _nets("fp32")
    batch = random_batch(11, SMALL["batch_size"])
    obs, action = jnp.asarray(batch.obs), jnp.asarray(batch.action)

    new, plain = (
        _actor_outputs(actor, params.actor, obs),
        _actor_outputs(plain_actor, params.actor, obs),
    )
    for name, x, y in zip(("pi", "d/dphi", "d/ds"), new, plain, strict=True):
        _assert_trees_close(x, y, rtol=1e-5, scale_atol=1e-6, err_msg=f"actor {name}")
    np.testing.assert_allclose(new[0], ref.actor(params.actor, batch.obs), rtol=1e-5, atol=1e-6)

    new = _critic_outputs(critic, params.critic, obs, action)
    plain = _critic_outputs(plain_critic, params.critic, obs, action)
    for name, x, y in zip(("Q", "dQ/dtheta", "dQ/da (sum)", "dQ/da"), new, plain, strict=True):
        _assert_trees_close(x, y, rtol=1e-5, scale_atol=1e-6, err_msg=f"critic {name}")
    for k in range(N_CRITICS):
        q_ref, dq_da_ref = ref.critic(
            jax.tree.map(lambda x, k=k: x[k], params.critic), batch.obs, batch.action
        )
        np.testing.assert_allclose(new[0][k], q_ref, rtol=1e-5, atol=1e-5)
        np.testing.assert_allclose(new[3][k], dq_da_ref, rtol=1e-4, atol=1e-5)


def test_switched_off_is_the_plain_layers_bit_for_bit(params, random_batch):
    """``bias_in_gemm=False`` (and ``networks.BIAS_IN_GEMM = False``) is the old arithmetic."""
    actor, critic, plain_actor, plain_critic = _nets("fp32", bias_in_gemm=False)
    batch = random_batch(12, SMALL["batch_size"])
    obs, action = jnp.asarray(batch.obs), jnp.asarray(batch.action)
    for x, y in zip(
        jax.tree.leaves(_actor_outputs(actor, params.actor, obs)),
        jax.tree.leaves(_actor_outputs(plain_actor, params.actor, obs)),
        strict=True,
    ):
        np.testing.assert_array_equal(x, y)
    for x, y in zip(
        jax.tree.leaves(_critic_outputs(critic, params.critic, obs, action)),
        jax.tree.leaves(_critic_outputs(plain_critic, params.critic, obs, action)),
        strict=True,
    ):
        np.testing.assert_array_equal(x, y)


def test_module_flag_is_the_default_of_the_factories(monkeypatch):
    """Off by default (the networks as trained so far); ``networks.BIAS_IN_GEMM`` or the
    factories' argument switch it on."""
    assert not networks.make_actor((8,)).bias_in_gemm
    assert not networks.make_critic(CFG).bias_in_gemm
    monkeypatch.setattr(networks, "BIAS_IN_GEMM", True)
    assert networks.make_actor((8,)).bias_in_gemm
    assert networks.make_critic(CFG, "bf16").bias_in_gemm
    assert not networks.make_actor((8,), bias_in_gemm=False).bias_in_gemm


# bf16: close, and no worse than the plain layers against fp32 -----------------------------


def test_bf16_is_close_to_the_plain_bf16_layers(params, random_batch):
    actor, critic, plain_actor, plain_critic = _nets("bf16")
    actor32, critic32, _, _ = _nets("fp32")
    batch = random_batch(13, SMALL["batch_size"])
    obs, action = jnp.asarray(batch.obs), jnp.asarray(batch.action)

    outs = {
        "new": (
            _actor_outputs(actor, params.actor, obs),
            _critic_outputs(critic, params.critic, obs, action),
        ),
        "plain": (
            _actor_outputs(plain_actor, params.actor, obs),
            _critic_outputs(plain_critic, params.critic, obs, action),
        ),
        "fp32": (
            _actor_outputs(actor32, params.actor, obs),
            _critic_outputs(critic32, params.critic, obs, action),
        ),
    }
    # fp32 results: the GEMMs take bf16 inputs but the heads, parameters and grads are fp32
    assert all(x.dtype == jnp.float32 for x in jax.tree.leaves(outs["new"]))
    new, plain, fp32 = (jax.tree.leaves(outs[k]) for k in ("new", "plain", "fp32"))
    for x, y, z in zip(new, plain, fp32, strict=True):
        x, y, z = (np.asarray(v, np.float64) for v in (x, y, z))
        scale = np.abs(z).max()
        # bf16 keeps 8 bits; a pre-activation near 0 can change sign (a ReLU mask bit) in one
        # bf16 program and not in the other, so single gradient entries may differ a lot:
        # compare mean errors, relative to the leaf's scale.
        err_new, err_plain = np.abs(x - z).mean(), np.abs(y - z).mean()
        assert np.abs(x - y).mean() <= 0.03 * scale
        assert err_new <= 0.03 * scale
        # and the bias row is no less accurate than the plain bf16 layers
        assert err_new <= 1.5 * err_plain + 1e-6 * scale


# The function itself ------------------------------------------------------------------------


@pytest.mark.parametrize("lead", [(), (5,), (3, 5)])
@pytest.mark.parametrize(("sizes", "k_align"), [((7,), 8), ((13, 2), 8), ((23,), 8), ((9,), 1)])
def test_affine_against_numpy(lead, sizes, k_align):
    """Any number of leading axes and input blocks; padded to k_align or not (23 + 1 = 24
    needs no padding)."""
    rng = np.random.default_rng(0)
    xs = [rng.normal(size=(*lead, n)).astype(np.float32) for n in sizes]
    kernels = [rng.normal(size=(n, 6)).astype(np.float32) for n in sizes]
    bias = rng.normal(size=6).astype(np.float32)
    want = sum(np.asarray(x, np.float64) @ k for x, k in zip(xs, kernels, strict=True)) + bias
    got = networks.affine(xs, kernels, bias, jnp.float32, True, k_align)
    assert got.shape == (*lead, 6) and got.dtype == jnp.float32
    np.testing.assert_allclose(got, want, rtol=1e-5, atol=1e-5)
    plain = networks.affine(xs, kernels, bias, jnp.float32, bias_in_gemm=False)
    np.testing.assert_allclose(plain, want, rtol=1e-5, atol=1e-5)


def _eqns(jaxpr) -> list:
    return list(jaxpr.eqns)  # the layer's program has no sub-jaxprs


def _batch_reductions(jaxpr) -> list:
    """reduce_sum equations that sum over an axis longer than 1 into a non-scalar: the bias
    gradient of a plain layer (the loss's own sum is a scalar)."""
    return [
        e
        for e in _eqns(jaxpr)
        if e.primitive.name == "reduce_sum"
        and e.outvars[0].aval.shape
        and any(e.invars[0].aval.shape[i] > 1 for i in e.params["axes"])
    ]


def test_bias_is_no_pass_of_its_own():
    """Forward: one dot_general and no add; backward: the bias gradient is a row of the
    weight gradient's dot_general, no sum over the batch. Under vmap (a population), the
    case XLA does not fuse into the GEMM's epilogue."""
    x = jnp.ones((4, 10, 12))  # [agents, batch, in]
    keys = jax.random.split(jax.random.PRNGKey(0), 4)

    def programs(layer):
        p = jax.vmap(layer.init)(keys, x)
        forward = jax.make_jaxpr(jax.vmap(layer.apply))(p, x).jaxpr

        def loss(p, x):
            return jnp.sum(jax.vmap(layer.apply)(p, x) ** 2)

        return forward, jax.make_jaxpr(jax.grad(loss, argnums=(0, 1)))(p, x).jaxpr

    forward, backward = programs(networks.Dense(16, bias_in_gemm=True))
    names = [e.primitive.name for e in _eqns(forward)]
    assert names.count("dot_general") == 1 and "add" not in names
    assert [e.primitive.name for e in _eqns(backward)].count("dot_general") == 3
    assert not _batch_reductions(backward)

    forward, backward = programs(networks.Dense(16, bias_in_gemm=False))
    assert "add" in [e.primitive.name for e in _eqns(forward)]
    assert len(_batch_reductions(backward)) == 1


# Through the learner -------------------------------------------------------------------------


def test_learner_steps_with_the_bias_row_match_the_plain_learner(agents, random_batch, monkeypatch):
    """ATD3+AfDP built with ``BIAS_IN_GEMM`` on: the same initial state, and one critic step
    and one actor step land where the plain learner's do, to fp32 rounding (Adam's first step
    is ±lr per entry, so an entry whose gradient is ~0 may step the other way)."""
    plain = agents["atd3"]
    monkeypatch.setattr(networks, "BIAS_IN_GEMM", True)
    assert_learner_steps_match(
        make_learner(plain.cfg), plain, random_batch(22, SMALL["batch_size"])
    )
