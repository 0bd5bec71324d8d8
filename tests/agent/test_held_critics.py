"""The critics held as their GEMM layers' matrices through a chunk (``agent/held_critics.py``).

Held, the fp32 augmented matrices are θ and θ^T: Adam and the soft update work on them.
The checks: holding and releasing gives back the flax trees and Adam's state exactly; the
held gradient is the flax gradient placed back (0 on structure, ±(g₊ - g₋) on the tied
rows); several updates, held or not, train the same; the structure stays exact through
them; the acting critic reads the held matrices; and only fp32 learners in the general program
hold them. (A chunk returns the flax trees: ``test_held_targets.py``.)
"""

from __future__ import annotations

import re

import jax
import jax.numpy as jnp
import numpy as np
import optax
import pytest

from advisor_jax.agent import gemm_layers, held_critics, networks
from advisor_jax.agent.config import HParams, parse_agent
from advisor_jax.agent.learner import make_learner
from advisor_jax.bench.learner_loop import SMALL, fill_replay
from advisor_jax.training import program
from tests.compare import assert_same_training

GEMM = networks.Layout(layers_in_gemm=True)
HELD = networks.Layout(layers_in_gemm=True, held_critics=True)
SIZES = dict(actor_hidden=(16, 16), critic_state_hidden=24, critic_hidden=(16, 16))


def _assert_equal(a, b):
    assert jax.tree.structure(a) == jax.tree.structure(b)
    for x, y in zip(jax.tree.leaves(a), jax.tree.leaves(b), strict=True):
        assert x.dtype == y.dtype
        np.testing.assert_array_equal(np.asarray(x), np.asarray(y))


def _cfg(precision="fp32"):
    sizes = {**SMALL, **SIZES, "batch_size": 32, "buffer_size": 256}
    return parse_agent("ATD3+AfDP", precision=precision, **sizes)


@pytest.fixture(scope="module")
def critics():
    cfg = _cfg()
    params = networks.init_critics(networks.make_critic(cfg), jax.random.key(0), cfg.n_critics)
    return params, held_critics.structure(jax.tree.map(lambda x: x[0], params))


def test_the_structure_marks_each_parameter_once_and_the_tied_rows(critics):
    params, s = critics
    one = jax.tree.map(lambda x: x[0], params)
    entries = sum(int(s.mask(i).sum()) for i in range(len(s.rows)))
    copies = sum(int((s.minus_rows(i)[:, None] & s.mask(i)).sum()) for i in range(len(s.rows)))
    assert entries - copies == networks.count_params(one)
    layer, first, pairs = s.tied
    built = gemm_layers.critic_matrices(one)[layer]
    k_a = one["params"]["hidden_0"]["kernel"]["action"]
    np.testing.assert_array_equal(built[first : first + 2 * pairs : 2, : k_a.shape[1]], k_a)
    np.testing.assert_array_equal(built[first + 1 : first + 2 * pairs : 2, : k_a.shape[1]], -k_a)


@pytest.mark.parametrize("mu_dtype", [None, jnp.bfloat16])
def test_hold_then_release_gives_back_the_trees_exactly(critics, mu_dtype):
    params, s = critics
    target = jax.tree.map(lambda x: x * 0.5, params)
    grads = jax.tree.map(lambda x: jnp.sin(x * 7.0), params)  # some non-zero moments
    adam = optax.adam(1e-3, mu_dtype=mu_dtype)
    opt = adam.update(grads, adam.init(params), params)[1]
    held = held_critics.hold(params, target, opt, s, jnp.bfloat16)
    n = len(held.online)
    assert [m.dtype for m in held.online_nets()] == [jnp.bfloat16] * (n - 1) + [jnp.float32]
    _assert_equal(held_critics.release(held, params, s), (params, target, opt))
    # ν is positive on the -K_a rows, as the square of their (negated) gradient
    nu = held.opt[0].nu[s.tied[0]]
    assert bool(jnp.all(nu >= 0))


def test_held_critics_at_a_wider_alignment_release_exactly():
    """The structure carries the matrices' alignment (``Layout.hidden_align``): held at 16 the
    [24 → 32 → 24 → 24] matrices give back the trees exactly."""
    cfg = _cfg()
    params = networks.init_critics(networks.make_critic(cfg), jax.random.key(2), cfg.n_critics)
    s = held_critics.structure(jax.tree.map(lambda x: x[0], params), align=16)
    opt = optax.adam(1e-3).init(params)
    held = held_critics.hold(params, params, opt, s, jnp.float32)
    assert s.align == 16 and [m.shape[1:] for m in held.online] == [
        (24, 32), (32, 24), (24, 24), (24, 1)
    ]  # fmt: skip
    _assert_equal(held_critics.release(held, params, s), (params, params, opt))


def test_the_held_gradient_is_the_trees_gradient_placed_back(critics):
    params, s = critics
    nets = jax.vmap(gemm_layers.critic_matrices)(params)
    d_nets = [jax.random.normal(jax.random.key(i), m.shape) for i, m in enumerate(nets)]
    _, pullback = jax.vjp(jax.vmap(gemm_layers.critic_matrices), params)
    (tree_grads,) = pullback(d_nets)
    got = held_critics.gradient(d_nets, s)
    placed = jax.vmap(gemm_layers.critic_matrices)(tree_grads)
    want = [jnp.where(s.mask(i), m, 0.0) for i, m in enumerate(placed)]
    _assert_equal(got, want)
    np.testing.assert_allclose(
        held_critics.global_norm(got, s), optax.global_norm(tree_grads), rtol=1e-5
    )


@pytest.mark.parametrize("precision", ["fp32", "bf16"])
def test_held_critics_train_as_the_trees_do(precision):
    cfg = _cfg(precision)
    replay = fill_replay(cfg.buffer_size, jax.random.key(1))
    hp = HParams(tau=0.5)  # the soft update moves the targets a lot

    def run(learner, state):
        def update(state, u):
            k_sample, k_critic = jax.random.split(jax.random.fold_in(jax.random.key(10), u))
            return learner.update(state, learner.sample(replay, k_sample), k_critic, hp, u)[:2]

        state = learner.hold(state)
        state, metrics = jax.lax.scan(update, state, jnp.arange(3 * cfg.delay))
        return learner.release(state), metrics

    held_learner, gemm_learner = make_learner(cfg, layout=HELD), make_learner(cfg, layout=GEMM)
    start = jax.jit(gemm_learner.init)(jax.random.key(0))
    held, held_metrics = jax.jit(lambda s: run(held_learner, s))(start)
    built, built_metrics = jax.jit(lambda s: run(gemm_learner, s))(start)
    assert held.held is None and held.critic_opt is not None
    assert_same_training(held, built, start, f"held critics, {precision}")
    np.testing.assert_allclose(
        held_metrics["grad_norm/critic"], built_metrics["grad_norm/critic"], rtol=1e-4
    )


@pytest.mark.parametrize("moments", ["fp32", "bf16", "bf16 and bf16 weights"])
def test_the_structure_stays_exact_through_updates(moments):
    # bf16 moments: v's stochastic rounding draws the same for the tied ±K_a rows (adam.dither);
    # bf16 weights: so does the rounding of the parameters and targets (adam.rounded_like)
    bf16, weights = moments != "fp32", moments.endswith("weights")
    layout = HELD._replace(bf16_first_moment=bf16, bf16_second_moment=bf16,
                           bf16_critic_weights=weights)  # fmt: skip
    cfg = _cfg("bf16")
    learner = make_learner(cfg, layout=layout)
    replay = fill_replay(cfg.buffer_size, jax.random.key(1))
    state = learner.hold(jax.jit(learner.init)(jax.random.key(0)))
    start = state.held
    for u in range(2 * cfg.delay):
        k_sample, k_critic = jax.random.split(jax.random.key(u))
        state = jax.jit(learner.update)(
            state, learner.sample(replay, k_sample), k_critic, HParams(tau=0.3), u
        )[0]
    s = held_critics.structure(jax.tree.map(lambda x: x[0], learner.release(state).critic))
    layer, first, pairs = s.tied
    for name in ("online", "target"):
        for i, (before, after) in enumerate(
            zip(start.online, getattr(state.held, name), strict=True)
        ):
            fixed = ~s.mask(i)
            np.testing.assert_array_equal(
                np.asarray(after)[..., fixed], np.asarray(before)[..., fixed]
            )
        tied = np.asarray(getattr(state.held, name)[layer])[..., first : first + 2 * pairs, :]
        np.testing.assert_array_equal(tied[..., 1::2, :], -tied[..., 0::2, :])
    build = jax.vmap(gemm_layers.critic_matrices, in_axes=(0, None))
    _assert_equal(state.held.online_nets(), build(learner.release(state).critic, jnp.bfloat16))


def test_the_selector_reads_the_held_critics():
    cfg = _cfg()
    learner = make_learner(cfg, layout=HELD)
    state = jax.jit(learner.init)(jax.random.key(3))
    obs = jax.random.uniform(jax.random.key(4), (8, 20))
    action = jax.random.uniform(jax.random.key(5), (8, 2))
    held = learner.hold(state)
    assert held.critic is None
    np.testing.assert_allclose(
        learner.q_select(held, obs, action), learner.q_select(state, obs, action), rtol=1e-5
    )


def test_which_learners_hold_their_critics_on_gpus():
    most = program.HELD_STEADY_BF16_AGENTS
    held = [
        ("general", "fp32", None),
        ("steady", "bf16", most),
        ("latency-bound", "bf16", 1),
        ("latency-bound", "bf16", None),
        ("latency-bound", "bf16", program.LATENCY_BOUND_AGENTS),
    ]
    for name, precision, agents in held:
        layout = program.program_layout(name, precision, "gpu", agents_per_device=agents)
        assert layout.held_critics, (name, precision, agents)
    not_held = [
        ("steady", "bf16", most + 1),
        ("steady", "bf16", None),
        ("steady", "fp32", 64),
        ("latency-bound", "fp32", program.LATENCY_BOUND_AGENTS),
        ("general", "bf16", 64),
    ]
    for name, precision, agents in not_held:
        layout = program.program_layout(name, precision, "gpu", agents_per_device=agents)
        assert not layout.held_critics, (name, precision, agents)
    assert program.program_layout("general", "fp32", "cpu") == networks.MODULES
    assert program.program_layout("steady", "bf16", "cpu", agents_per_device=8) == networks.MODULES


def test_the_norms_sum_of_squares_runs_along_the_rows_first():
    """``_sum_of_squares`` is Σ g², and the compiled program keeps its row sums (a reduction
    over the last axis only, the one XLA emits in Adam's pass) instead of one merged sum."""
    g = jax.random.normal(jax.random.key(3), (3, 2, 40, 24))
    got = jax.jit(jax.vmap(held_critics._sum_of_squares))(g)
    np.testing.assert_allclose(got, jnp.sum(g**2, axis=(1, 2, 3)), rtol=1e-5)
    hlo = jax.jit(jax.vmap(held_critics._sum_of_squares)).lower(g).compile().as_text()
    assert re.search(r"f32\[3,2,40\]\{[0-9,]*\} reduce\(", hlo), "the row sums were merged away"
