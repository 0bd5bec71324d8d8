"""A bf16 learner's Adam with its moments in bf16 (``networks.Layout.bf16_first_moment`` and
``bf16_second_moment``, on GPUs; ``agent/adam.py``): where the moments are stored, that only
their rounding changes the updates, and that a checkpoint written with fp32 moments resumes
into the new storage."""

from __future__ import annotations

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from advisor_jax.agent import networks
from advisor_jax.agent.config import HParams, parse_agent
from advisor_jax.agent.learner import make_learner
from advisor_jax.bench.learner_loop import SMALL, fill_replay
from advisor_jax.training import checkpoint

SIZES = dict(actor_hidden=(16, 16), critic_state_hidden=24, critic_hidden=(16, 16))
MOMENT = networks.Layout(bf16_first_moment=True)
MOMENTS = networks.Layout(bf16_first_moment=True, bf16_second_moment=True)


def _cfg(precision):
    return parse_agent("ATD3+AfDP", **{**SMALL, **SIZES, "batch_size": 32, "buffer_size": 256,
                                       "precision": precision})  # fmt: skip


def _moments(opt_state):
    (adam, _) = opt_state  # optax.adam: (ScaleByAdamState, scale by the learning rate)
    return adam.mu, adam.nu


@pytest.mark.parametrize(
    "precision, layout, mu_dtype, nu_dtype",
    [
        ("bf16", MOMENT, jnp.bfloat16, jnp.float32),
        ("bf16", MOMENTS, jnp.bfloat16, jnp.bfloat16),
        ("fp32", MOMENTS, jnp.float32, jnp.float32),
    ],
)
def test_only_a_bf16_learners_moments_are_bf16(precision, layout, mu_dtype, nu_dtype):
    state = make_learner(_cfg(precision), layout=layout).init(jax.random.key(0))
    for opt in (state.critic_opt, state.actor_opt):
        mu, nu = _moments(opt)
        assert {x.dtype for x in jax.tree.leaves(mu)} == {jnp.dtype(mu_dtype)}
        assert {x.dtype for x in jax.tree.leaves(nu)} == {jnp.dtype(nu_dtype)}
    assert {x.dtype for x in jax.tree.leaves(state.critic)} == {jnp.dtype(jnp.float32)}
    plain = make_learner(_cfg("bf16")).init(jax.random.key(0))  # the CPU's layout
    for moment in _moments(plain.critic_opt):
        assert {x.dtype for x in jax.tree.leaves(moment)} == {jnp.dtype(jnp.float32)}


def test_the_updates_differ_by_the_moments_rounding_alone():
    cfg = _cfg("bf16")
    replay = fill_replay(cfg.buffer_size, jax.random.key(1))
    start = make_learner(cfg).init(jax.random.key(0))
    finals = {}
    layouts = (("fp32 moments", networks.MODULES), ("bf16 m", MOMENT), ("bf16 m, v", MOMENTS))
    for name, layout in layouts:
        learner = make_learner(cfg, layout=layout)
        state = learner.init(jax.random.key(0))  # same parameters, the moment's own dtype
        update = jax.jit(learner.update)
        for u in range(cfg.delay + 1):
            keys = jax.random.split(jax.random.key(10 + u))
            state, _, nonfinite = update(
                state, learner.sample(replay, keys[0]), keys[1], HParams(), u
            )
            assert not bool(nonfinite)
        finals[name] = state
    steps, lr = cfg.delay + 1, max(HParams().lr_critic, HParams().lr_actor)
    for part in ("critic", "actor"):
        fp32, *bf16s = [jax.tree.leaves(getattr(s, part)) for s in finals.values()]
        first = jax.tree.leaves(getattr(start, part))
        moved = max(float(jnp.max(jnp.abs(x - x0))) for x, x0 in zip(fp32, first, strict=True))
        assert moved > 0, part
        for bf16 in bf16s:
            diff = max(float(jnp.max(jnp.abs(x - y))) for x, y in zip(fp32, bf16, strict=True))
            # Adam's steps are lr · m̂ / (√v̂ + ε) ≤ lr (about) each: rounding m or v to bf16
            # (2⁻⁸) changes a step by far less than the step; a sign flip of a near-zero
            # gradient's moment can move one parameter by up to 2 lr.
            assert 0 < diff <= 2 * lr * steps, part


def test_a_checkpoint_with_fp32_moments_resumes_in_bf16(tmp_path):
    fp32 = make_learner(_cfg("bf16")).init(jax.random.key(0))
    checkpoint.save_step(tmp_path / "checkpoints", 7, jax.tree.map(np.asarray, fp32))
    abstract = jax.eval_shape(make_learner(_cfg("bf16"), layout=MOMENTS).init, jax.random.key(0))
    restored, step = checkpoint.restore_latest(tmp_path / "checkpoints", abstract)
    assert step == 7
    for moment in _moments(restored.critic_opt):
        assert {x.dtype for x in jax.tree.leaves(moment)} == {jnp.dtype(jnp.bfloat16)}
    for x, y in zip(jax.tree.leaves(restored.critic), jax.tree.leaves(fp32.critic), strict=True):
        np.testing.assert_array_equal(np.asarray(x), np.asarray(y))  # fp32 leaves exactly
