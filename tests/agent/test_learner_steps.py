"""make_learner: parameter counts, init, what each step touches, numpy references, vmap.

The references are the numpy networks of conftest.py (float64), so these tests check the
flax forward pass, ∇_a Q, Eq. 2 with AfP, the TD targets, the losses, the soft updates and
the first Adam step independently of the code under test.
"""

import dataclasses

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from advisor_jax.agent.config import AgentConfig, HParams, parse_agent
from advisor_jax.agent.learner import make_learner
from advisor_jax.agent.networks import count_params
from tests.compare import assert_same_training

# float32 leaves, as the trainer passes them: Python floats would be a second signature
# of the jitted steps (a recompile) next to the stacked HParams of the vmap test.
HP = jax.tree.map(
    np.float32, HParams(lr_actor=1e-3, lr_critic=2e-3, tau=0.25, gamma=0.8, beta=0.05)
)
CRITIC_FIELDS = {"critic", "critic_opt", "critic_updates"}
ACTOR_FIELDS = {"actor", "actor_opt", "actor_updates", "target_actor", "target_critic"}
ALL_FIELDS = CRITIC_FIELDS | ACTOR_FIELDS


def _first(tree):
    return jax.tree.map(lambda x: np.asarray(x)[0], tree)


def _halve_targets(state):
    """Targets unlike the online networks, so a test sees which one a rule reads."""
    return state.replace(
        target_actor=jax.tree.map(lambda x: 0.5 * np.asarray(x), state.target_actor),
        target_critic=jax.tree.map(lambda x: 0.5 * np.asarray(x), state.target_critic),
    )


def _leaves(*trees):
    """Matching leaves of same-structure trees, as numpy arrays."""
    return zip(*(map(np.asarray, jax.tree.leaves(t)) for t in trees), strict=True)


def _changed(before, after) -> set[str]:
    return {
        name
        for name in ALL_FIELDS
        if any(
            not np.array_equal(a, b)
            for a, b in _leaves(getattr(before, name), getattr(after, name))
        )
    }


def _steps(before, after) -> np.ndarray:
    """|Δ| of every parameter, flattened."""
    return np.concatenate([np.abs(b - a).ravel() for a, b in _leaves(before, after)])


@pytest.mark.parametrize("agent", ["DDPG", "ATD3+AfDP"])
def test_paper_parameter_counts(agent):
    cfg = parse_agent(agent)  # the paper's sizes
    state = jax.eval_shape(make_learner(cfg).init, jax.random.key(0))
    assert count_params(state.actor) == 193_502
    assert count_params(state.target_actor) == 193_502
    n = cfg.n_critics
    assert {leaf.shape[0] for leaf in jax.tree.leaves(state.critic)} == {n}
    assert count_params(state.critic) == n * 823_701
    assert count_params(state.target_critic) == n * 823_701


def test_make_learner_rejects_non_config():
    with pytest.raises(TypeError, match="AgentConfig"):
        make_learner({"algo": "ddpg"})
    assert callable(make_learner(AgentConfig()).init)


# ddpg covers the DPG actor and one critic, atd3 the Eq. 2 actor with AfP and twin critics.
@pytest.mark.parametrize("name", ["ddpg", "atd3"])
def test_init_and_what_each_step_touches(agents, random_batch, name):
    agent = agents[name]
    state = agent.init(jax.random.key(0))
    for online, target in ((state.actor, state.target_actor), (state.critic, state.target_critic)):
        for a, b in zip(jax.tree.leaves(online), jax.tree.leaves(target), strict=True):
            np.testing.assert_array_equal(a, b)  # Alg. 2 step 4
    assert jax.tree.leaves(state.critic)[0].shape[0] == agent.cfg.n_critics
    assert int(state.critic_updates) == 0 and int(state.actor_updates) == 0

    batch = random_batch(1, 64)
    after_critic, metrics = agent.critic_step(state, batch, jax.random.key(2), HP)
    assert _changed(state, after_critic) == CRITIC_FIELDS
    assert int(after_critic.critic_updates) == 1 and int(after_critic.actor_updates) == 0
    after_actor, metrics_actor = agent.actor_step(after_critic, batch, HP)
    assert _changed(after_critic, after_actor) == ACTOR_FIELDS
    assert int(after_actor.critic_updates) == 1 and int(after_actor.actor_updates) == 1
    for m in (metrics, metrics_actor):
        assert all(v.shape == () for v in m.values())
        assert all(np.isfinite(v) for k, v in m.items() if not k.startswith("diag/"))
    assert set(metrics) == {"loss/critic", "q/mean", "q/target", "q/clipped", "grad_norm/critic"}
    assert set(metrics_actor) == {"loss/actor", "advisor/replaced", "grad_norm/actor"} | {
        "diag/grad_q_rms", "diag/step", "diag/advisor_gap", "diag/q_gain", "diag/saturated"
    }  # fmt: skip


@pytest.mark.parametrize("name", ["ddpg", "atd3"])
def test_critic_step_against_reference(agents, random_batch, ref, name):
    agent = agents[name]
    state = _halve_targets(agent.init(jax.random.key(3)))
    batch = random_batch(4, 64)
    key = jax.random.key(5)
    new, metrics = agent.critic_step(state, batch, key, HP)

    next_a = ref.actor(state.target_actor, batch.next_obs)
    if agent.cfg.twin:  # Alg. A3 steps 10-11, with the draws the step makes from `key`
        xi = np.asarray(jax.random.normal(key, next_a.shape))
        noise = np.clip(HP.target_noise * xi, -HP.target_noise_clip, HP.target_noise_clip)
        next_a = np.clip(next_a + noise, [0.0, -1.0], [1.0, 1.0])
    next_q = ref.critics(state.target_critic, batch.next_obs, next_a).min(axis=0)
    target = batch.reward + HP.gamma * (1.0 - batch.terminal) * next_q
    q = ref.critics(state.critic, batch.obs, batch.action)  # [n_critics, n]
    tol = dict(rtol=1e-4, atol=1e-5)
    np.testing.assert_allclose(metrics["q/target"], target.mean(), **tol)
    np.testing.assert_allclose(metrics["loss/critic"], ((target - q) ** 2).mean(), **tol)
    np.testing.assert_allclose(metrics["q/mean"], q.mean(), **tol)
    # First Adam step: Δθ = -lr·g/(|g| + 1e-8), so |Δθ| = lr_critic wherever |g| >> 1e-8.
    steps = _steps(state.critic, new.critic)
    assert steps.max() <= HP.lr_critic * (1 + 1e-4)
    assert np.median(steps) == pytest.approx(HP.lr_critic, rel=1e-3)


def test_clip_q_target_bounds_the_td_targets(agents, random_batch, ref):
    """With return bounds and ``clip_q_target`` = 1 the critic regresses on clip(Q̂, lo, hi)
    (R35); with the switch off, or without bounds, on Q̂ itself. The bounds are made tight
    (±0.3·γ) so that many of the hand-checked targets fall outside."""
    agent = agents["ddpg"]
    learner = make_learner(agent.cfg, lambda gamma: (-0.3 * gamma, 0.3 * gamma))
    step = jax.jit(learner.critic_step)
    state = _halve_targets(agent.init(jax.random.key(3)))
    batch, key = random_batch(4, 64), jax.random.key(5)
    next_q = ref.critics(state.target_critic, batch.next_obs, ref.actor(state.target_actor,
                         batch.next_obs)).min(axis=0)  # fmt: skip
    target = batch.reward + HP.gamma * (1.0 - batch.terminal) * next_q
    bound = 0.3 * HP.gamma
    q = ref.critics(state.critic, batch.obs, batch.action)
    tol = dict(rtol=1e-4, atol=1e-5)
    for switch, expected in ((1.0, np.clip(target, -bound, bound)), (0.0, target)):
        new, metrics = step(state, batch, key, HP.replace(clip_q_target=np.float32(switch)))
        np.testing.assert_allclose(metrics["q/target"], expected.mean(), **tol)
        np.testing.assert_allclose(metrics["loss/critic"], ((expected - q) ** 2).mean(), **tol)
        outside = np.mean(np.abs(target) > bound) if switch else 0.0
        assert 0.2 < np.mean(np.abs(target) > bound) < 0.9
        np.testing.assert_allclose(metrics["q/clipped"], outside, atol=1e-6)
    # Switched off, the bounded learner takes the unbounded learner's step.
    off = HP.replace(clip_q_target=np.float32(0.0))
    for a, b in _leaves(step(state, batch, key, off)[0].critic,
                        agent.critic_step(state, batch, key, off)[0].critic):  # fmt: skip
        np.testing.assert_allclose(a, b, rtol=1e-6, atol=1e-9)
    # Without bounds the switch has nothing to clip to: Q̂ as printed.
    _, unbounded = agent.critic_step(state, batch, key, HP.replace(clip_q_target=np.float32(1)))
    np.testing.assert_allclose(unbounded["q/target"], target.mean(), **tol)
    assert float(unbounded["q/clipped"]) == 0.0


@pytest.mark.parametrize("name", ["ddpg", "addpg", "atd3"])
def test_actor_step_against_reference(agents, random_batch, ref, name):
    agent = agents[name]
    state = _halve_targets(agent.init(jax.random.key(6)))
    batch = random_batch(7, 64)
    new, metrics = agent.actor_step(state, batch, HP)

    q1 = _first(state.critic)  # Q_1 drives the actor (Alg. A3 steps 17, 19)
    actions = ref.actor(state.actor, batch.obs)
    q_act, grad = ref.critic(q1, batch.obs, actions)
    replaced = np.zeros(64, bool)
    if agent.cfg.advisor_target:
        a_hat = actions + HP.beta * grad  # Eq. (2)
        if agent.cfg.advisor_policy:  # Alg. 2 steps 11-13
            q_hat = ref.critic(q1, batch.obs, a_hat)[0]
            q_adv = ref.critic(q1, batch.obs, batch.advisor_action)[0]
            assert np.abs(q_adv - q_hat).min() > 1e-4  # no near-ties: the mask is well defined
            replaced = q_adv > q_hat
            assert 0 < replaced.sum() < 64  # the batch exercises both outcomes
            a_hat = np.where(replaced[:, None], batch.advisor_action, a_hat)
        loss = np.mean(np.sum((a_hat - actions) ** 2, axis=-1))  # Eq. (3)
    else:
        loss = -q_act.mean()  # DPG
    np.testing.assert_allclose(metrics["loss/actor"], loss, rtol=1e-4, atol=1e-7)
    assert float(metrics["advisor/replaced"]) == pytest.approx(replaced.mean(), abs=1e-7)

    # Soft updates (Eqs. 6, 7) of every target, with the new actor and the current critic.
    def check_soft(old_target, online, new_target):
        for t, o, n in _leaves(old_target, online, new_target):
            np.testing.assert_allclose(n, HP.tau * o + (1 - HP.tau) * t, rtol=1e-5, atol=1e-7)

    check_soft(state.target_actor, new.actor, new.target_actor)
    check_soft(state.target_critic, state.critic, new.target_critic)
    assert _steps(state.actor, new.actor).max() <= HP.lr_actor * (1 + 1e-4)  # first Adam step


def test_addpg_without_afp_steps_like_ddpg_under_adam(agents, random_batch):
    # Without AfP, ∇_φ L_π = J^T (2/n)(π - Â) = -2β J^T ∇_a Q / n: a positive multiple of the
    # DPG gradient -J^T ∇_a Q / n. Adam is invariant to a constant gradient scale except
    # through its ε = 1e-8 (visible only where |g| ≲ 1e-6), so ADDPG and DDPG take the same
    # actor step. A sign error in Eq. (2) would send them opposite ways.
    state = agents["ddpg"].init(jax.random.key(11))
    batch = random_batch(12, 64)
    ddpg, _ = agents["ddpg"].actor_step(state, batch, HP)
    addpg, _ = agents["addpg"].actor_step(state, batch, HP)
    step_ddpg = np.concatenate([(a - b).ravel() for a, b in _leaves(ddpg.actor, state.actor)])
    step_addpg = np.concatenate([(a - b).ravel() for a, b in _leaves(addpg.actor, state.actor)])
    moved = step_ddpg != 0
    np.testing.assert_array_equal(np.sign(step_addpg[moved]), np.sign(step_ddpg[moved]))
    assert np.median(np.abs(step_addpg - step_ddpg)) < HP.lr_actor * 1e-4


def test_afp_stops_after_advisor_policy_episodes(agents, random_batch):
    # ATD3+AfDP replaces while episode <= N_P and afterwards steps exactly like ATD3 without AfP.
    atd3 = agents["atd3"]
    state = atd3.init(jax.random.key(13))
    batch = random_batch(14, 64)
    hp = HP.replace(advisor_policy_episodes=np.float32(5))
    replacing, during = atd3.actor_step(state, batch, hp, jnp.int32(5))
    after, after_metrics = atd3.actor_step(state, batch, hp, jnp.int32(6))
    assert float(during["advisor/replaced"]) > 0 and float(after_metrics["advisor/replaced"]) == 0
    plain = make_learner(dataclasses.replace(atd3.cfg, advisor_policy=False))
    expected, _ = jax.jit(plain.actor_step)(state, batch, hp)
    # Two programs: equal up to the order XLA sums in (tests/compare.py), while the step that
    # still replaces lands elsewhere.
    assert_same_training(after.actor, expected.actor, state.actor, "after N_P")
    with pytest.raises(AssertionError):
        assert_same_training(replacing.actor, expected.actor, state.actor, "before N_P")


def test_q_select_is_min_over_critics(agents, random_batch, ref):
    batch = random_batch(10, 16)
    for name in ("ddpg", "atd3"):
        agent = agents[name]
        state = agent.init(jax.random.key(9))
        q = ref.critics(state.critic, batch.obs, batch.action)
        got = jax.jit(agent.learner.q_select)(state, batch.obs, batch.action)
        np.testing.assert_allclose(got, q.min(axis=0), rtol=1e-4, atol=1e-5)
    assert np.abs(q[0] - q[1]).min() > 1e-3  # the twin critics are distinct networks


def _stack(trees):
    return jax.tree.map(lambda *xs: jnp.stack(xs), *trees)


def test_vmap_over_agents_equals_separate_calls(agents, random_batch):
    agent = agents["atd3"]  # every rule: smoothing, twin critics, Eq. 2, AfP
    hps = [
        HParams(gamma=0.9, tau=0.1, beta=0.01, lr_actor=1e-4, lr_critic=1e-3),
        HParams(gamma=0.5, tau=0.3, beta=0.2, lr_actor=1e-3, lr_critic=3e-3, target_noise=0.3),
        HParams(
            gamma=0.99, tau=0.01, beta=0.05, lr_actor=3e-5, lr_critic=1e-4, target_noise_clip=0.05
        ),
    ]
    hps = [jax.tree.map(np.float32, hp) for hp in hps]
    states = [agent.init(jax.random.key(20 + i)) for i in range(3)]
    batches = [random_batch(30 + i, 64) for i in range(3)]
    keys = list(jax.random.split(jax.random.key(40), 3))

    def both(state, batch, key, hp):
        state, m_critic = agent.learner.critic_step(state, batch, key, hp)
        state, m_actor = agent.learner.actor_step(state, batch, hp)
        return state, {**m_critic, **m_actor}

    vmapped, vm_metrics = jax.jit(jax.vmap(both))(
        _stack(states), _stack(batches), jnp.stack(keys), _stack(hps)
    )
    for i in range(3):
        state_i, metrics_c = agent.critic_step(states[i], batches[i], keys[i], hps[i])
        state_i, metrics_a = agent.actor_step(state_i, batches[i], hps[i])
        # The batched and the lone matmuls sum in CPU-dependent orders; the bound is
        # relative to how far the step moved each leaf (tests/compare.py says why).
        vm_i = jax.tree.map(lambda x, i=i: np.asarray(x)[i], vmapped)
        assert_same_training(vm_i, state_i, states[i], f"agent {i}")
        for k, v in {**metrics_c, **metrics_a}.items():
            np.testing.assert_allclose(np.asarray(vm_metrics[k])[i], v, rtol=1e-5, atol=1e-6)
    # The agents really differ (different γ, σ̄, c).
    assert len({round(float(x), 4) for x in vm_metrics["q/target"]}) == 3


def test_bf16_learner_computes_in_bf16_and_keeps_fp32_state(agents, random_batch):
    """AgentConfig.precision = "bf16": the hidden layers' GEMMs take bf16 inputs (a real
    change of program), parameters, targets and Adam stay fp32, and one critic and one
    actor step land near the fp32 learner's."""
    fp32 = agents["atd3"]
    learner = make_learner(dataclasses.replace(fp32.cfg, precision="bf16"))
    state = fp32.init(jax.random.PRNGKey(0))
    batch = random_batch(3, fp32.cfg.batch_size)
    key = jax.random.PRNGKey(1)
    jaxpr = str(jax.make_jaxpr(learner.critic_step)(state, batch, key, HP))
    assert "bf16[" in jaxpr and "bf16[" not in str(
        jax.make_jaxpr(fp32.learner.critic_step)(state, batch, key, HP)
    )
    (s16, m16), (s32, m32) = (
        jax.jit(learner.critic_step)(state, batch, key, HP),
        fp32.critic_step(state, batch, key, HP),
    )
    (s16, a16), (s32, a32) = (  # jitted: eagerly the bf16 step compiles op by op
        jax.jit(learner.actor_step)(s16, batch, HP),
        fp32.actor_step(s32, batch, HP),
    )
    assert all(x.dtype == jnp.float32 for x in jax.tree.leaves(s16) if x.dtype.kind == "f")
    for name in ("loss/critic", "q/mean", "q/target", "loss/actor"):
        m_bf16, m_fp32 = {**m16, **a16}[name], {**m32, **a32}[name]
        np.testing.assert_allclose(m_bf16, m_fp32, rtol=0.05, atol=1e-3, err_msg=name)
    # the parameter updates agree in direction: bf16 rounding is ~0.4 % per input
    for a, b, c in _leaves(state.critic, s32.critic, s16.critic):
        d32, d16 = (b - a).ravel(), (c - a).ravel()
        assert d32 @ d16 > 0.9 * np.linalg.norm(d32) * np.linalg.norm(d16)
    # the selector acts with the fp32 critic whatever the learner's precision
    q_fp32 = fp32.learner.q_select(state, batch.obs, batch.action)
    np.testing.assert_array_equal(learner.q_select(state, batch.obs, batch.action), q_fp32)


def test_unknown_precision_is_named():
    with pytest.raises(ValueError, match="unknown precision 'fp16'"):
        AgentConfig(precision="fp16")
