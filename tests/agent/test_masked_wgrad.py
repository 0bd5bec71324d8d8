"""The critic's first layer with its weight gradient and ReLU mask in one kernel
(``agent/masked_wgrad.py``), run here in Pallas's interpreter: the same gradient as the mask
and GEMM it replaces, its edge tiles included, and the same learner updates."""

from __future__ import annotations

import json
import os
import subprocess
import sys
from pathlib import Path

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from advisor_jax.agent import gemm_layers, masked_wgrad, networks
from advisor_jax.agent.config import HParams, parse_agent
from advisor_jax.agent.learner import make_learner
from advisor_jax.bench.learner_loop import SMALL, fill_replay
from tests.compare import assert_same_training


def _inputs(n, k, m, dtype, seed=0):
    keys = jax.random.split(jax.random.key(seed), 3)
    return tuple(jax.random.normal(key, shape, dtype) for key, shape in
                 zip(keys, [(n, k), (n, m), (n, m)], strict=True))  # fmt: skip


def _reference(x, y, g):
    masked = jnp.where(y > 0, g, 0).astype(jnp.float32)
    return x.astype(jnp.float32).T @ masked


# (n, k, m): tiles that divide; a batch whose last row tile overlaps the one before (40 =
# 32 + 8) and columns whose last tile does too (72 = 64 + 8); the paper's first layer.
@pytest.mark.parametrize("n, k, m", [(64, 16, 128), (40, 24, 72), (1000, 24, 1008)])
def test_the_kernel_is_the_masked_weight_gradient(n, k, m):
    x, y, g = _inputs(n, k, m, jnp.float32)
    got = masked_wgrad.weight_gradient(x, y, g)
    assert got.shape == (k, m) and got.dtype == jnp.float32
    want = _reference(x, y, g)
    np.testing.assert_allclose(got, want, rtol=1e-5, atol=1e-4 * float(jnp.max(jnp.abs(want))))


# Rows split over programs: none (as 8+ agents' twin critics run), two, more than one per
# row tile (an empty share), an uneven last share (1,000 rows are 32 tiles: 11, 11, 10).
@pytest.mark.parametrize("splits", [1, 2, 3, 64])
@pytest.mark.parametrize("n, k, m", [(40, 24, 72), (1000, 24, 1008)])
def test_split_rows_give_the_same_gradient(n, k, m, splits):
    x, y, g = _inputs(n, k, m, jnp.float32, seed=splits)
    got = masked_wgrad.kernel(x, y, g, splits=splits)
    assert got.shape == (k, m) and got.dtype == jnp.float32
    want = _reference(x, y, g)
    np.testing.assert_allclose(got, want, rtol=1e-5, atol=1e-4 * float(jnp.max(jnp.abs(want))))


@pytest.mark.parametrize("splits", [1, 3])
def test_a_row_summed_twice_or_a_column_left_out_would_show(splits):
    # All ones: every entry of the gradient counts the batch's rows, n, exactly.
    n, k, m = 40, 24, 72
    ones = jnp.ones((n, k)), jnp.ones((n, m)), jnp.ones((n, m))
    got = masked_wgrad.kernel(*ones, splits=splits)
    np.testing.assert_array_equal(got, np.full((k, m), n))


def test_few_layers_split_their_rows_and_many_do_not():
    # The paper's first layer, 8 column tiles and 32 row tiles: 1 agent's twin critics get
    # 8 programs per tile (128 in all), 4 agents' 2, from 8 agents on the tiles alone fill.
    n, m = 1000, 1008
    assert [masked_wgrad.row_splits(b, n, m) for b in (1, 2, 8, 16, 256)] == [16, 8, 2, 1, 1]
    assert masked_wgrad.row_splits(1, 40, 72) == 2  # no more shares than row tiles
    for batch in (1, 2, 4, 8):
        programs = batch * 8 * masked_wgrad.row_splits(batch, n, m)
        assert masked_wgrad.PROGRAMS // 2 < programs <= masked_wgrad.PROGRAMS


@pytest.mark.parametrize("splits", [1, 2])
def test_bf16_rounds_once_from_an_fp32_sum(splits):
    x, y, g = _inputs(64, 24, 128, jnp.bfloat16)
    got = masked_wgrad.kernel(x, y, g, splits=splits)
    assert got.dtype == jnp.bfloat16
    want = _reference(x, y, g)
    np.testing.assert_allclose(got.astype(jnp.float32), want, rtol=2**-7, atol=1e-2)


def test_vmapped_kernels_are_separate_kernels():
    x, y, g = (a.reshape(3, 2, *a.shape[1:]) for a in _inputs(6, 24, 72, jnp.float32))
    x, y, g = (jnp.broadcast_to(a[:, :, None], (3, 2, 40, a.shape[-1])) for a in (x, y, g))
    x = x * jnp.arange(1, 41, dtype=jnp.float32)[:, None]  # rows differ
    got = jax.vmap(jax.vmap(masked_wgrad.weight_gradient))(x, y, g)
    want = jnp.einsum("abnk,abnm->abkm", x, jnp.where(y > 0, g, 0))
    np.testing.assert_allclose(got, want, rtol=1e-5, atol=1e-3)


def test_a_layer_below_the_tiles_is_refused_by_name():
    with pytest.raises(ValueError, match=r"\[8, 24\] x \[8, 72\]"):
        masked_wgrad.weight_gradient(*_inputs(8, 24, 72, jnp.float32))
    assert not masked_wgrad.fits(8, 24, 72) and masked_wgrad.fits(16, 16, 16)


def test_the_layer_has_gemm_layers_value_and_gradients():
    x, _, _ = _inputs(40, 24, 72, jnp.float32)
    matrix = jax.random.normal(jax.random.key(5), (24, 72)) / 5
    cotangent = jax.random.normal(jax.random.key(6), (40, 72))

    def loss(layer):
        return lambda x, w: jnp.sum(layer(x, w) * cotangent)

    want = jax.grad(loss(gemm_layers._hidden), (0, 1))(x, matrix)
    got = jax.grad(loss(gemm_layers.first_critic_layer), (0, 1))(x, matrix)
    value = gemm_layers.first_critic_layer(x, matrix)
    np.testing.assert_array_equal(value, gemm_layers._hidden(x, matrix))
    for a, b in zip(got, want, strict=True):
        np.testing.assert_allclose(a, b, rtol=1e-5, atol=1e-5)


def test_the_critic_falls_back_below_the_tiles():
    # A batch of 8 has no tile: the kernel's layout computes as gemm_layers does.
    cfg = parse_agent("ATD3+AfDP", **SMALL)
    critic = networks.make_critic(cfg)
    params = networks.init_critics(critic, jax.random.key(0), 1)
    params = jax.tree.map(lambda a: a[0], params)
    obs, action = jnp.ones((8, 20)), jnp.full((8, 2), 0.5)
    matrices = gemm_layers.critic_matrices(params)
    np.testing.assert_array_equal(
        gemm_layers.critic_forward(matrices, obs, action, first_layer_kernel=True),
        gemm_layers.critic_forward(matrices, obs, action),
    )


# bf16: the kernel takes its mask from the layer's input (weight_gradient_from_input).
@pytest.mark.parametrize("precision", ["fp32", "bf16"])
def test_a_learner_with_the_kernel_takes_the_same_updates(precision):
    sizes = dict(actor_hidden=(16, 16), critic_state_hidden=24, critic_hidden=(16, 16))
    settings = {**SMALL, **sizes, "batch_size": 40, "buffer_size": 256, "precision": precision}
    cfg = parse_agent("ATD3+AfDP", **settings)
    replay = fill_replay(cfg.buffer_size, jax.random.key(1))
    layouts = {"kernel": networks.Layout(True, True, True), "xla": networks.Layout(True, True)}
    start = make_learner(cfg, layout=layouts["xla"]).init(jax.random.key(0))
    states = {}
    for name, layout in layouts.items():
        learner = make_learner(cfg, layout=layout)
        state, update = start, jax.jit(learner.update)
        for u in range(cfg.delay + 1):  # critic steps and one actor step
            keys = jax.random.split(jax.random.key(10 + u))
            state, _, nonfinite = update(
                state, learner.sample(replay, keys[0]), keys[1], HParams(), u
            )
            assert not bool(nonfinite)
        states[name] = state
    assert_same_training(states["kernel"], states["xla"], start, "learner")


@pytest.fixture(scope="module", params=["fp32", "bf16"])
def sharded_population(request, tmp_path_factory):
    """masked_wgrad_worker.py's output: 4 learners with the kernel, one update sharded over 2
    forced CPU devices and on one device; bf16 with the mask from the layer's input."""
    worker = Path(__file__).with_name("masked_wgrad_worker.py")
    env = dict(os.environ)  # with the suite's XLA_FLAGS: the worker adds its devices
    path = tmp_path_factory.mktemp("sharded") / "states.npz"
    command = [sys.executable, str(worker), str(path), request.param]
    done = subprocess.run(command, env=env, capture_output=True, text=True, timeout=600)
    assert done.returncode == 0, done.stderr[-3000:]
    out = json.loads(done.stdout.splitlines()[-1])
    with np.load(path) as saved:
        states = {name: [saved[f"{name}/{i}"] for i in range(len(saved.files) // 3)]
                  for name in ("start", "one", "two")}  # fmt: skip
    return out, states


def test_a_sharded_population_runs_each_devices_kernels_on_that_device(sharded_population):
    # The agents' kernels stay on their devices: nothing gathered, the same updates.
    out, states = sharded_population
    assert out["collectives"] == []
    assert_same_training(states["two"], states["one"], states["start"], "sharded learner")


def test_the_bare_kernel_would_be_gathered_onto_every_device(sharded_population):
    # What masked_wgrad.weight_gradient exists for: jax.vmap of the bare Pallas call is one
    # custom call the partitioner gathers whole, the check above would see it.
    gathers = [c for c in sharded_population[0]["plain_collectives"] if c["op"] == "all-gather"]
    assert gathers and all("masked_weight_gradient" in c["source"] for c in gathers)


@pytest.mark.parametrize("splits", [1, 3])
@pytest.mark.parametrize("n, k, m", [(40, 24, 72), (1000, 24, 1008)])
def test_the_mask_from_the_input_is_the_forward_mask(n, k, m, splits):
    # bf16 x and matrix: the products are exact, so x @ w > 0 in the kernel is y > 0 of the
    # forward's output (here XLA's dot), and the gradients agree as the y-reading kernel's do.
    x, _, g = _inputs(n, k, m, jnp.bfloat16, seed=splits)
    w = (jax.random.normal(jax.random.key(9), (k, m)) / 4).astype(jnp.bfloat16)
    y = gemm_layers._hidden(x, w)
    got = masked_wgrad.kernel(x, w, g, splits=splits, from_input=True)
    assert got.shape == (k, m) and got.dtype == jnp.bfloat16
    want = masked_wgrad.kernel(x, y, g, splits=splits)
    np.testing.assert_array_equal(np.asarray(got), np.asarray(want))
    assert float(jnp.mean((y > 0).astype(jnp.float32))) > 0.3  # a mask that masks


def test_vmapped_kernels_from_the_input_are_separate_kernels():
    x, _, g = (a.reshape(3, 2, 40, -1) for a in _inputs(240, 24, 72, jnp.bfloat16))
    w = (jax.random.normal(jax.random.key(3), (3, 2, 24, 72)) / 4).astype(jnp.bfloat16)
    got = jax.vmap(jax.vmap(masked_wgrad.weight_gradient_from_input))(x, w, g)
    mask = jnp.einsum("abnk,abkm->abnm", x, w, preferred_element_type=jnp.float32) > 0
    want = jnp.einsum(
        "abnk,abnm->abkm", x.astype(jnp.float32), jnp.where(mask, g, 0).astype(jnp.float32)
    )
    np.testing.assert_allclose(got.astype(jnp.float32), want, rtol=2**-7, atol=2e-2)


@pytest.mark.parametrize("dtype, used", [(jnp.bfloat16, "from_input"), (jnp.float32, "output")])
def test_bf16_layers_take_the_mask_from_their_input(monkeypatch, dtype, used):
    calls = []
    for name, tag in (("weight_gradient", "output"), ("weight_gradient_from_input", "from_input")):
        inner = getattr(masked_wgrad, name)
        monkeypatch.setattr(masked_wgrad, name, lambda *a, f=inner, t=tag: calls.append(t) or f(*a))
    x, _, _ = _inputs(40, 24, 72, dtype)
    matrix = (jax.random.normal(jax.random.key(5), (24, 72)) / 5).astype(dtype)
    cotangent = jax.random.normal(jax.random.key(6), (40, 72)).astype(dtype)

    def loss(layer):
        return lambda w: jnp.sum((layer(x, w) * cotangent).astype(jnp.float32))

    got = jax.grad(loss(gemm_layers.first_critic_layer))(matrix)
    want = jax.grad(loss(gemm_layers._hidden))(matrix)
    assert calls == [used]
    tol = dict(rtol=2**-7, atol=2e-2) if dtype == jnp.bfloat16 else dict(rtol=1e-5, atol=1e-5)
    np.testing.assert_allclose(got.astype(jnp.float32), want.astype(jnp.float32), **tol)


def test_a_bf16_learner_updates_bit_for_bit_as_with_the_output_mask(monkeypatch):
    # The mask from the input is the forward's mask here (exact bf16 products, and the sum's
    # order at these sizes gives no sign a different side of 0): the learner's updates are
    # those of the kernel that reads the layer's output, bit for bit.
    sizes = dict(actor_hidden=(16, 16), critic_state_hidden=24, critic_hidden=(16, 16))
    settings = {**SMALL, **sizes, "batch_size": 40, "buffer_size": 256, "precision": "bf16"}
    cfg = parse_agent("ATD3+AfDP", **settings)
    replay = fill_replay(cfg.buffer_size, jax.random.key(1))
    layout = networks.Layout(True, True, True)
    start = make_learner(cfg, layout=layout).init(jax.random.key(0))

    def trained():
        learner, state = make_learner(cfg, layout=layout), start
        update = jax.jit(learner.update)
        for u in range(cfg.delay + 1):
            keys = jax.random.split(jax.random.key(10 + u))
            batch = learner.sample(replay, keys[0])
            state = update(state, batch, keys[1], HParams(), u)[0]
        return state

    from_input = trained()
    output_mask = lambda x, w, g: masked_wgrad.weight_gradient(x, gemm_layers._hidden(x, w), g)  # noqa: E731
    monkeypatch.setattr(masked_wgrad, "weight_gradient_from_input", output_mask)
    for a, b in zip(jax.tree.leaves(from_input), jax.tree.leaves(trained()), strict=True):
        np.testing.assert_array_equal(np.asarray(a), np.asarray(b))
    moved = jax.tree.leaves(from_input.critic)[0]
    assert not np.array_equal(np.asarray(moved), np.asarray(jax.tree.leaves(start.critic)[0]))
