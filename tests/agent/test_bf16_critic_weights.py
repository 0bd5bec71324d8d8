"""bf16 learners' held critics in bf16 only (``networks.Layout.bf16_critic_weights``).

The hidden matrices θ and θ^T are held in bf16, with no fp32 master: Adam's step and the soft
update are taken in fp32 and rounded stochastically (``adam.apply_updates``,
``held_critics.soft_update``). The checks: an update far below bf16's resolution still moves
a parameter by itself on average (rounded to nearest it would not move at all); nothing is
held twice; a chunk's start and end are exact; and a few updates move the critics as the
fp32 master's do, to within the rounding.
"""

from __future__ import annotations

import jax
import jax.numpy as jnp
import numpy as np
import optax

from advisor_jax.agent import adam
from advisor_jax.agent.config import HParams
from advisor_jax.agent.learner import make_learner
from advisor_jax.bench.learner_loop import fill_replay
from tests.agent.test_held_critics import HELD, _cfg

MOMENTS = HELD._replace(bf16_first_moment=True, bf16_second_moment=True)
WEIGHTS = MOMENTS._replace(bf16_critic_weights=True)


def test_a_bf16_parameter_moves_by_its_update_on_average():
    """Every positive bf16 value of 40 binades (5,120 parameters, each its own draw) updated by
    0.128 of its bf16 step: the moves, in steps, average 0.128 (standard error 0.005); each is
    one step or none. Rounded to nearest no parameter would move."""
    bits = (jnp.arange(5120, dtype=jnp.uint32) + (107 << 7)).astype(jnp.uint16)
    p = jax.lax.bitcast_convert_type(bits, jnp.bfloat16)  # 2⁻²⁰ up to 2²⁰
    step = 2.0 ** jnp.floor(jnp.log2(p.astype(jnp.float32))) * 2.0**-7  # bf16's, per binade
    u = 0.128 * step
    moved = adam.apply_updates(p, u, 7)
    assert moved.dtype == jnp.bfloat16
    steps = (np.asarray(moved, np.float64) - np.asarray(p, np.float64)) / np.asarray(step)
    assert set(np.unique(np.round(steps, 6))) <= {0.0, 1.0}  # one neighbour or the other
    assert abs(steps.mean() - 0.128) < 0.02, steps.mean()
    nearest = (p.astype(jnp.float32) + u).astype(jnp.bfloat16)
    np.testing.assert_array_equal(nearest, p)


def test_fp32_parameters_update_as_optax_does():
    p = jax.random.normal(jax.random.key(1), (64, 8))
    u = 1e-3 * jax.random.normal(jax.random.key(2), (64, 8))
    np.testing.assert_array_equal(adam.apply_updates(p, u, 7), optax.apply_updates(p, u))


def test_the_same_small_step_at_every_step_moves_a_parameter_by_it():
    """64 bf16 parameters near 1 (step 2⁻⁷), each moved by 10⁻⁴ at each of 1,000 steps: they
    move by 0.1 on average (standard error 0.004). The draws must change from step to step
    (``dither``'s salt): θ + u repeats while θ stays put, and one draw for it would round the
    same way every time, moving no parameter or each by 1,000 steps of 2⁻⁷."""
    start = (1.0 + 2**-7 * jnp.arange(64)).astype(jnp.bfloat16)
    u = jnp.full(start.shape, 1e-4, jnp.float32)
    end = jax.lax.fori_loop(0, 1000, lambda i, p: adam.apply_updates(p, u, i), start)
    moved = np.asarray(end, np.float64) - np.asarray(start, np.float64)
    assert abs(moved.mean() - 0.1) < 0.02, moved.mean()


def test_held_in_bf16_there_is_no_master_and_no_copy_and_release_is_exact():
    cfg = _cfg("bf16")
    learner = make_learner(cfg, layout=WEIGHTS)
    state = learner.hold(jax.jit(learner.init)(jax.random.key(0)))
    held = state.held
    n = len(held.online)
    for matrices in (held.online, held.target):
        assert [m.dtype for m in matrices] == [jnp.bfloat16] * (n - 1) + [jnp.float32]
    assert held.online_copy is None and held.target_copy is None
    # released as fp32 trees of bf16 values, which the next chunk holds exactly again
    released = learner.release(state)
    for leaf in jax.tree.leaves(released.critic):
        assert leaf.dtype == jnp.float32
    again = learner.hold(released).held
    for a, b in zip(jax.tree.leaves(again), jax.tree.leaves(held), strict=True):
        np.testing.assert_array_equal(np.asarray(a), np.asarray(b))


def _moved(layout, updates: int):
    """(start, end) critics and target critics (fp32 trees) of ``updates`` updates with a
    large learning rate and τ, so that the updates outweigh bf16's rounding."""
    cfg = _cfg("bf16")
    learner = make_learner(cfg, layout=layout)
    replay = fill_replay(cfg.buffer_size, jax.random.key(1))
    hp = HParams(lr_critic=1e-2, tau=0.5)

    def run(state):
        def update(state, u):
            k_sample, k_critic = jax.random.split(jax.random.fold_in(jax.random.key(10), u))
            return learner.update(state, learner.sample(replay, k_sample), k_critic, hp, u)[0], ()

        held = learner.hold(state)
        start = learner.release(held)  # what the chunk starts from (bf16 values if held so)
        end = learner.release(jax.lax.scan(update, held, jnp.arange(updates))[0])
        return start, end

    start, end = jax.jit(run)(jax.jit(learner.init)(jax.random.key(0)))
    return (start.critic, start.target_critic), (end.critic, end.target_critic)


def test_bf16_weights_move_the_critics_as_the_fp32_master_does():
    """Per leaf, the bf16 weights' move ‖Δ‖ is the fp32 master's to within 10 %, and in its
    direction (cosine > 0.95): the stochastic rounding adds noise of at most one bf16 step per
    entry and update, far below moves of 10⁻² per update."""
    updates = 3 * _cfg("bf16").delay
    (m0, t0), (m1, t1) = _moved(MOMENTS, updates)
    (w0, v0), (w1, v1) = _moved(WEIGHTS, updates)
    for trees in [(m0, m1, w0, w1), (t0, t1, v0, v1)]:
        for a0, a1, b0, b1 in zip(*map(jax.tree.leaves, trees), strict=True):
            da = np.asarray(a1, np.float64) - np.asarray(a0, np.float64)
            db = np.asarray(b1, np.float64) - np.asarray(b0, np.float64)
            na, nb = np.linalg.norm(da), np.linalg.norm(db)
            assert na > 0
            assert 0.9 < nb / na < 1.1, (nb, na)
            assert np.sum(da * db) / (na * nb) > 0.95


def _trained(layout, updates: int = 400):
    """The critic loss and batch-mean Q of each of ``updates`` updates at the default
    hyperparameters (learning rates 10⁻³, τ = 0.005) on a fixed replay buffer."""
    cfg = _cfg("bf16")
    learner = make_learner(cfg, layout=layout)
    replay = fill_replay(cfg.buffer_size, jax.random.key(1))

    def update(state, u):
        k_sample, k_critic = jax.random.split(jax.random.fold_in(jax.random.key(10), u))
        batch = learner.sample(replay, k_sample)
        state, metrics = learner.update(state, batch, k_critic, HParams(), u)[:2]
        return state, (metrics["loss/critic"], metrics["q/mean"])

    def run(state):
        return jax.lax.scan(update, learner.hold(state), jnp.arange(updates))[1]

    loss, q = jax.jit(run)(jax.jit(learner.init)(jax.random.key(0)))
    return np.asarray(loss), np.asarray(q)


def test_bf16_weights_train_as_the_fp32_master_over_400_updates():
    """Small steps at the default learning rates and τ, most far below bf16's resolution:
    the last 50 updates' mean Q within 0.05 of the fp32 master's, and their mean loss within
    30 % (measured on this CPU: 0.001 and 6 %; other batches move Q by 0.01). Draws that
    repeated from step to step (an unsalted ``dither``) left parameters stuck and ended 0.2
    away in Q."""
    loss_master, q_master = _trained(MOMENTS)
    loss_bf16, q_bf16 = _trained(WEIGHTS)
    assert abs(q_bf16[-50:].mean() - q_master[-50:].mean()) < 0.05
    assert abs(loss_bf16[-50:].mean() / loss_master[-50:].mean() - 1) < 0.3
