"""Unit tests of the rule-based advisor (Algorithm A1, Table A1) in advisor_jax/agent/advisor.py.

Signs (contract/spec.py): sensor index 0 looks left (+90°), index 7 right (-90°); ω > 0 turns
left; δ > 0 means the goal is on the left. Hand computations use Table A1:
b_L = [-0.1 … -0.8, 0 × 8], b_R = [-0.8 … -0.1, 0 × 8], d_nd = 0.6, d_dmax = 0.2.
"""

import math

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from advisor_jax.agent.advisor import AdvisorParams, advisor_action

advise = jax.jit(advisor_action)


def _obs(prox=1.0, delta=0.0, dist=2.0, vel=(0.0, 0.0), **sensor_values):
    """Observation with every proximity reading = prox except ``p<i>=value`` overrides."""
    p = np.full(16, prox, np.float32)
    for name, value in sensor_values.items():
        p[int(name[1:])] = value
    return jnp.asarray(np.concatenate([p, [delta, dist, *vel]]).astype(np.float32))


def _act(obs, params=None):
    v, w = np.asarray(advisor_action(obs, params) if params is not None else advise(obs))
    return float(v), float(w)


def test_goal_reaching_branch_values():
    # min P = 1.0 > T_o = 0.5: ω = tanh(m1 δ), V = 1 - exp(-m2 d) (Eqs. 9, 10).
    v, w = _act(_obs(delta=0.5, dist=0.3))
    assert w == pytest.approx(math.tanh(0.5), abs=1e-6)  # 0.46212
    assert v == pytest.approx(1.0 - math.exp(-1.5), abs=1e-6)  # 0.77687
    v, w = _act(_obs(delta=-2.0, dist=0.0))
    assert w == pytest.approx(math.tanh(-2.0), abs=1e-6) and v == pytest.approx(0.0, abs=1e-7)


def test_goal_on_the_left_turns_left():
    for delta in (0.1, 1.0, 3.0):
        assert _act(_obs(delta=delta))[1] > 0
        assert _act(_obs(delta=-delta))[1] < 0
    # Obstacles farther than T_o are ignored: P = 0.55 everywhere is still goal reaching.
    v, w = _act(_obs(prox=0.55, delta=0.3, dist=1.0))
    assert w == pytest.approx(math.tanh(0.3), abs=1e-6)
    assert v == pytest.approx(1.0 - math.exp(-5.0), abs=1e-6)


def test_braitenberg_by_hand():
    # p3 (index 2) = 0.4 → det = 1 - (0.4 - 0.2)/0.4 = 0.5;
    # p4 (index 3) = 0.1 < d_dmax → clamped to 0.2 → det = 1; all others 1.0 → det = 0.
    # V = 1 + ½[(b_R + b_L)·det] = 1 + ½[(-0.9)(0.5) + (-0.9)(1)] = 0.325
    # ω = ½ m3 [(b_R - b_L)·det] = ½[(-0.6 + 0.3)(0.5) + (-0.5 + 0.4)(1)] = -0.125
    v, w = _act(_obs(p2=0.4, p3=0.1))
    assert v == pytest.approx(0.325, abs=1e-6)
    assert w == pytest.approx(-0.125, abs=1e-6)
    # The mirror image (indices 5 and 4) turns the other way at the same speed.
    v, w = _act(_obs(p5=0.4, p4=0.1))
    assert v == pytest.approx(0.325, abs=1e-6)
    assert w == pytest.approx(0.125, abs=1e-6)


def test_obstacle_left_turns_right_and_right_turns_left():
    # Left sensors 0..2 at 0.3: det = 0.75 each; ω = ½·0.75·(-0.7 - 0.5 - 0.3) = -0.5625;
    # V = 1 + ½·0.75·(-2.7) = -0.0125 → clipped to 0.
    v, w = _act(_obs(p0=0.3, p1=0.3, p2=0.3))
    assert w == pytest.approx(-0.5625, abs=1e-6) and v == 0.0
    v, w = _act(_obs(p5=0.3, p6=0.3, p7=0.3))
    assert w == pytest.approx(0.5625, abs=1e-6) and v == 0.0
    # Whatever the goal says: the obstacle rule wins below T_o.
    assert _act(_obs(p1=0.45, delta=2.0))[1] < 0
    assert _act(_obs(p6=0.45, delta=-2.0))[1] > 0


def test_threshold_equality_and_rear_sensors():
    # min P = T_o exactly: Braitenberg (Alg. A1's else). Every det = 1 - 0.3/0.4 = 0.25:
    # V = 1 + ½·0.25·Σ(b_R + b_L) = 1 + 0.125·(-7.2) = 0.1; ω = 0 by symmetry.
    v, w = _act(_obs(prox=0.5, delta=1.0))
    assert v == pytest.approx(0.1, abs=1e-6) and w == pytest.approx(0.0, abs=1e-6)
    # Only a rear reading is close: Braitenberg mode, but rear weights are 0 ⇒ V = 1, ω = 0.
    v, w = _act(_obs(p11=0.15, delta=1.0, dist=0.1))
    assert v == pytest.approx(1.0) and w == pytest.approx(0.0, abs=1e-7)


def test_parameters_and_clipping():
    # Physical T_o = 0.6: P = 0.55 everywhere now triggers Braitenberg (det = 0.125 each):
    # V = 1 + ½·0.125·(-7.2) = 0.55.
    v, _ = _act(_obs(prox=0.55, delta=0.3), AdvisorParams(obstacle_threshold=0.6))
    assert v == pytest.approx(0.55, abs=1e-6)
    # m3 = 3 with left sensors 0..3 touching (det = 1): ω = 1.5·(-1.6) = -2.4 → clipped to -1.
    _, w = _act(_obs(p0=0.1, p1=0.1, p2=0.1, p3=0.1), AdvisorParams(m3=3.0))
    assert w == -1.0


def test_output_bounds_on_random_inputs():
    rng = np.random.default_rng(0)
    n = 5000
    prox = np.concatenate(
        [
            rng.uniform(0.0, 0.7, (n // 2, 16)),  # near obstacles
            rng.uniform(0.45, 1.0, (n - n // 2, 16)),  # ~22 % of these are goal reaching
        ]
    )
    obs = np.concatenate(
        [
            prox,
            rng.uniform(-np.pi, np.pi, (n, 1)),
            rng.uniform(0.0, 7.5, (n, 1)),
            rng.normal(0.0, 1.0, (n, 2)),
        ],
        axis=1,
    ).astype(np.float32)
    actions = np.asarray(jax.jit(jax.vmap(advisor_action))(jnp.asarray(obs)))
    assert actions.shape == (n, 2) and actions.dtype == np.float32
    assert np.isfinite(actions).all()
    assert (actions[:, 0] >= 0).all() and (actions[:, 0] <= 1).all()
    assert (actions[:, 1] >= -1).all() and (actions[:, 1] <= 1).all()
    goal_mode = obs[:, :16].min(axis=1) > 0.5
    assert 0 < goal_mode.sum() < n  # both branches exercised
    # vmap agrees with one-at-a-time calls.
    for i in (0, 1, n // 2, n - 1):
        np.testing.assert_allclose(actions[i], advise(jnp.asarray(obs[i])), atol=1e-6)


def test_vmap_over_advisor_params():
    params = jax.tree.map(lambda x: jnp.stack([jnp.asarray(x)] * 2), AdvisorParams())
    params = params.replace(obstacle_threshold=jnp.array([0.5, 0.6], jnp.float32))
    out = jax.vmap(advisor_action, in_axes=(None, 0))(_obs(prox=0.55, delta=0.3), params)
    np.testing.assert_allclose(out[0], [1.0 - math.exp(-10.0), math.tanh(0.3)], atol=1e-6)
    np.testing.assert_allclose(out[1], [0.55, 0.0], atol=1e-6)
