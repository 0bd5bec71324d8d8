"""The two selectable readings of Eq. (2) and the actor diagnostics, on hand-made batches.

Same hand-made critic as test_learner_rules.py: Q(s, a) = -||a - c(s)||², c(s) = s[:2], so
∇_a Q = -2 (a - c). For the four samples there (a - c = (-0.2, 0.2), (0, 0.1), 0, (-1, 1)):
∇_a Q = (0.4, -0.4), (0, -0.2), 0, (2, -2); ‖∇_a Q‖² = 0.32, 0.04, 0, 8, so
rms ‖∇_a Q‖ = √(8.36 / 4) = 1.445683.
"""

import math

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from advisor_jax.agent.config import HParams, preset, validate_hparams
from advisor_jax.agent.diagnostics import actor_diagnostics
from advisor_jax.agent.update_rules import addpg_actor_targets, eq2_step
from tests.agent.test_learner_rules import ACTIONS, ADVISOR, OBS, quadratic_q

GRAD_Q = jnp.array([[0.4, -0.4], [0.0, -0.2], [0.0, 0.0], [2.0, -2.0]])
RMS = math.sqrt(8.36 / 4)  # 1.445683
NORMS = np.array([math.sqrt(0.32), 0.2, 0.0, math.sqrt(8.0)])


def test_literal_step_is_beta_times_the_gradient():
    np.testing.assert_allclose(eq2_step(GRAD_Q, 0.1, 0.0), 0.1 * GRAD_Q, atol=1e-7)


def test_scale_free_step_has_rms_length_beta_whatever_the_q_scale():
    for q_scale in (1.0, 1e-3, 250.0):  # the same critic, rewards scaled
        step = np.asarray(eq2_step(q_scale * GRAD_Q, 0.1, 1.0))
        # sample 3: 0.1 · (2, -2) / 1.445683 = (0.138343, -0.138343), whatever the scale
        np.testing.assert_allclose(step[3], [0.138343, -0.138343], rtol=1e-5)
        np.testing.assert_allclose(np.sqrt(np.mean(np.sum(step**2, -1))), 0.1, rtol=1e-6)
        np.testing.assert_allclose(step[2], [0.0, 0.0])  # a zero gradient stays zero
    # An all-zero batch gives a zero step, not NaN.
    np.testing.assert_array_equal(eq2_step(jnp.zeros((3, 2)), 0.1, 1.0), np.zeros((3, 2)))


def test_clipping_the_target_changes_what_afp_compares():
    """β = 1 (literal): â = a + ∇_aQ = (0.7, -0.2), (0.5, -0.1), (0, 0.5), (2, -2).

    Sample 3's â = (2, -2) lies outside the box. Unclipped, Q(â) = -2 < Q(a_adv) = -0.17, so
    AfP replaces it; clipped to (1, -1) = c, Q(â) = 0 > -0.17 and the actor keeps its own
    target. Sample 0 is replaced either way (Q(â) = -0.08 < -0.01), 1 and 2 kept.
    """
    unclipped = addpg_actor_targets(quadratic_q, OBS, ACTIONS, ADVISOR, 1.0, True)
    clipped = addpg_actor_targets(quadratic_q, OBS, ACTIONS, ADVISOR, 1.0, True, clip_target=1.0)
    np.testing.assert_array_equal(unclipped.replaced, [True, False, False, True])
    np.testing.assert_array_equal(clipped.replaced, [True, False, False, False])
    np.testing.assert_allclose(
        unclipped.a_hat, [[0.5, 0.1], [0.5, -0.1], [0.0, 0.5], [0.9, -0.6]], atol=1e-6
    )
    np.testing.assert_allclose(
        clipped.a_hat, [[0.5, 0.1], [0.5, -0.1], [0.0, 0.5], [1.0, -1.0]], atol=1e-6
    )
    # Q(s, a_adv) - Q(s, â) before replacement: 0.07, -0.33, 0, -0.17 (clipped).
    np.testing.assert_allclose(clipped.q_gain, [0.07, -0.33, 0.0, -0.17], atol=1e-6)
    np.testing.assert_allclose(clipped.grad_q, GRAD_Q, atol=1e-6)
    # Without the switch, â is the paper's, unclipped.
    plain = addpg_actor_targets(quadratic_q, OBS, ACTIONS, ADVISOR, 1.0, False)
    np.testing.assert_allclose(plain.a_hat[3], [2.0, -2.0], atol=1e-6)


def test_actor_diagnostics_by_hand():
    targets = addpg_actor_targets(quadratic_q, OBS, ACTIONS, ADVISOR, 1.0, True, clip_target=1.0)
    diag = {
        k: float(v) for k, v in actor_diagnostics(ACTIONS, ADVISOR, GRAD_Q, targets, True).items()
    }
    assert diag["diag/grad_q_rms"] == pytest.approx(RMS, rel=1e-6)
    assert diag["diag/step"] == pytest.approx(NORMS.mean(), rel=1e-6)  # β = 1: step = ∇_aQ
    # Only sample 0 was replaced: ‖(0.5, 0.1) - (0.3, 0.2)‖ = √0.05.
    assert diag["diag/advisor_gap"] == pytest.approx(math.sqrt(0.05), rel=1e-6)
    assert diag["diag/q_gain"] == pytest.approx((0.07 - 0.33 + 0.0 - 0.17) / 4, abs=1e-6)
    # Heads: V = 0.3, 0.5, 0, 0 (two within 0.01 of 0), ω = 0.2, 0.1, 0.5, 0 (none): 2 of 8.
    assert diag["diag/saturated"] == pytest.approx(0.25)


def test_diagnostics_not_defined_are_nan():
    """DDPG/TD3 have no Eq. (2) target; ADDPG without AfP has no Q gain; no replaced sample
    has no advisor gap."""
    dpg = actor_diagnostics(ACTIONS, ADVISOR, GRAD_Q, None, False)
    assert float(dpg["diag/grad_q_rms"]) == pytest.approx(RMS, rel=1e-6)
    assert all(math.isnan(float(dpg[k])) for k in ("diag/step", "diag/advisor_gap", "diag/q_gain"))
    plain = addpg_actor_targets(quadratic_q, OBS, ACTIONS, ADVISOR, 0.1, False)
    no_afp = actor_diagnostics(ACTIONS, ADVISOR, plain.grad_q, plain, False)
    assert math.isnan(float(no_afp["diag/q_gain"])) and math.isnan(
        float(no_afp["diag/advisor_gap"])
    )
    assert float(no_afp["diag/step"]) == pytest.approx(0.1 * NORMS.mean(), rel=1e-5)


@pytest.mark.parametrize("name", ["beta_normalize", "clip_actor_target", "clip_q_target"])
def test_switches_take_zero_or_one(name):
    validate_hparams(HParams(**{name: 1.0}))
    with pytest.raises(ValueError, match=f"{name}=0.5 is a switch: 0 or 1"):
        validate_hparams(HParams(**{name: 0.5}))


def test_only_the_stable_preset_departs_from_the_literal_eqs():
    """paper/physical/quick keep Eqs. (2) and (4) as printed; stable differs from paper only
    in the settings the 16-seed evidence supports (results/afp_collapse/,
    results/q_target_clip.md)."""
    for name in ("paper", "physical", "quick"):
        hp = preset(name)[1]
        assert (hp.beta_normalize, hp.clip_actor_target, hp.clip_q_target) == (0.0, 0.0, 0.0)
    (paper_cfg, paper), (stable_cfg, stable) = preset("paper"), preset("stable")
    assert stable_cfg == paper_cfg
    assert stable == paper.replace(
        beta=1.0, beta_normalize=1.0, clip_actor_target=1.0, clip_q_target=1.0
    )


@pytest.mark.parametrize("name", ["ddpg", "addpg", "atd3"])
def test_learner_reports_diagnostics(agents, random_batch, name):
    """Every algorithm's actor step reports the same diag keys; the scale-free step of the
    real learner has rms length β."""
    agent = agents[name]
    state = agent.init(jax.random.key(3))
    hp = HParams(beta=0.05, beta_normalize=1.0, clip_actor_target=1.0)
    _, metrics = agent.actor_step(state, random_batch(5, 64), hp)
    assert {"diag/grad_q_rms", "diag/step", "diag/saturated"} <= set(metrics)
    assert np.isfinite(float(metrics["diag/grad_q_rms"]))
    assert 0.0 <= float(metrics["diag/saturated"]) <= 1.0
    if agent.cfg.advisor_target:
        assert 0.0 < float(metrics["diag/step"]) <= 0.05 + 1e-6  # mean ≤ rms = β
    else:
        assert math.isnan(float(metrics["diag/step"]))
