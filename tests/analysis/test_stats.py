"""advisor_jax.stats on hand-computed inputs, and against rliable where it installs."""

from __future__ import annotations

import math

import numpy as np
import pytest

from advisor_jax import stats

T_975_2 = 4.302652729911275  # Student-t 97.5 % quantile, 2 degrees of freedom (tables)


def test_t_interval_of_three_values():
    iv = stats.t_interval([1.0, 2.0, 3.0, None, float("nan")])  # None / NaN: diverged seeds
    assert iv.n == 3 and iv.estimate == 2.0
    assert iv.half == pytest.approx(T_975_2 * 1.0 / math.sqrt(3))
    assert stats.format_interval(iv) == "2.0 ± 2.5"


def test_no_interval_is_shown_below_three_seeds():
    iv = stats.t_interval([0.5, 0.7])
    assert not math.isnan(iv.half)  # computed (12.7 × sd / √2) ...
    assert stats.format_interval(iv, scale=100) == "60.0 (n=2)"  # ... but not shown
    assert stats.format_interval(stats.t_interval([0.4]), scale=100) == "40.0 (n=1)"
    assert stats.format_interval(stats.t_interval([])) == "–"


def test_iqm_trims_a_quarter_off_each_end():
    assert stats.iqm([1, 2, 3, 4, 5, 6, 7, 8]) == 4.5  # mean of 3, 4, 5, 6
    assert stats.iqm([1, 2, 3, 4, 100]) == 3.0  # int(5 / 4) = 1 off each end
    assert stats.iqm(np.array([[1, 8], [2, 7], [3, 6], [4, 5]])) == 4.5  # runs and tasks pooled


def test_bootstrap_interval_of_constant_scores_is_a_point_and_holds_the_estimate():
    assert stats.iqm_interval([0.6] * 5)[:3] == (0.6, 0.6, 0.6)
    x = [0.1, 0.5, 0.55, 0.6, 0.62, 0.7, 0.9, 0.95]
    iv = stats.iqm_interval(x, reps=2000)
    assert iv.estimate == pytest.approx(stats.iqm(x))
    assert 0.1 <= iv.low <= iv.estimate <= iv.high <= 0.95
    assert stats.iqm_interval(x, reps=2000) == iv  # seeded: a report reproduces


def test_stratified_resampling_keeps_each_task_to_its_own_runs():
    # task 0 scores are all < 1, task 1 all > 10: a resample mixing them would show it
    x = np.array([[0.1, 11.0], [0.2, 12.0], [0.3, 13.0]])
    idx = stats.stratified_resamples(3, 2, 500, np.random.default_rng(0))
    sample = np.take_along_axis(x[None], idx, axis=1)
    assert (sample[..., 0] < 1).all() and (sample[..., 1] > 10).all()


def test_probability_of_improvement_counts_ties_half():
    # pairs (x, y): (1, 0) 1, (1, 2) 0, (2, 0) 1, (2, 2) 0.5 -> 2.5 / 4
    assert stats.probability_of_improvement([1, 2], [0, 2]).estimate == 0.625
    assert stats.probability_of_improvement([3, 4], [1, 2]).estimate == 1.0
    # two tasks, averaged: task 0 gives 1, task 1 gives 0
    x, y = np.array([[1.0, 0.0], [1.0, 0.0]]), np.array([[0.0, 1.0], [0.0, 1.0]])
    assert stats.probability_of_improvement(x, y).estimate == 0.5
    iv = stats.probability_of_improvement([0.5, 0.6, 0.7, 0.9], [0.4, 0.5, 0.6, 0.65])
    assert 0.0 <= iv.low <= iv.estimate <= iv.high <= 1.0


def test_paired_difference_uses_the_seeds_both_have():
    x = {0: 0.8, 1: 0.6, 2: 0.7, 5: 0.9}
    y = {0: 0.5, 1: 0.6, 2: 0.4, 3: 0.1, 5: None}  # seed 5: diverged on one side
    p = stats.paired_difference(x, y)
    assert p.seeds == [0, 1, 2]
    np.testing.assert_allclose(p.differences, [0.3, 0.0, 0.3])
    sd = math.sqrt(((0.1) ** 2 * 2 + 0.2**2) / 2)  # mean 0.2; deviations 0.1, -0.2, 0.1
    assert p.interval.estimate == pytest.approx(0.2)
    assert p.interval.half == pytest.approx(T_975_2 * sd / math.sqrt(3))
    assert p.verdict == "not resolved"  # 0.2 ± 0.43
    assert stats.paired_difference({0: 0.5}, {0: 0.4}) is None


def test_verdicts():
    assert stats.verdict(stats.Interval(0.2, 0.1, 0.3, 8)) == "holds"
    assert stats.verdict(stats.Interval(-0.2, -0.3, -0.1, 8)) == "reversed"
    assert stats.verdict(stats.Interval(-0.2, -0.3, -0.1, 8), better="below") == "holds"
    assert stats.verdict(stats.Interval(0.0, -0.1, 0.1, 8)) == "not resolved"


def test_welch_interval_by_hand():
    iv = stats.welch_interval([1, 2, 3], [2, 4, 6])
    va, vb = 1 / 3, 4 / 3  # s² / n: 1 / 3 and 4 / 3
    df = (va + vb) ** 2 / (va**2 / 2 + vb**2 / 2)
    from scipy import stats as sps

    assert iv.estimate == -2.0
    assert iv.half == pytest.approx(sps.t.ppf(0.975, df) * math.sqrt(va + vb))
    assert df == pytest.approx(2.9412, abs=1e-4)


def test_summary_is_plain_numbers():
    s = stats.summary([0.5, 0.6, 0.7, None])
    assert s["seeds"] == 3 and s["mean"] == pytest.approx(0.6) and s["min"] == 0.5


# -- the same numbers as rliable (skipped where rliable does not install) -------------------


def test_iqm_and_probability_of_improvement_match_rliable():
    rliable = pytest.importorskip("rliable.metrics")
    rng = np.random.default_rng(3)
    x, y = rng.uniform(size=(16, 2)), rng.uniform(size=(12, 2))
    x[:4] = np.round(x[:4], 1)
    y[:4] = np.round(y[:4], 1)  # some ties
    assert stats.iqm(x) == pytest.approx(rliable.aggregate_iqm(x))
    assert stats.probability_of_improvement(x, y).estimate == pytest.approx(
        rliable.probability_of_improvement(x, y)
    )


def test_bootstrap_intervals_match_rliable():
    library = pytest.importorskip("rliable.library")
    metrics = pytest.importorskip("rliable.metrics")
    rng = np.random.default_rng(4)
    x, y = rng.uniform(size=(16, 2)), rng.uniform(size=(16, 2)) - 0.1
    _, ci = library.get_interval_estimates(
        {"x": x}, lambda s: np.array([metrics.aggregate_iqm(s)]), reps=20_000,
        random_state=np.random.RandomState(0),
    )  # fmt: skip
    ours = stats.iqm_interval(x, reps=20_000)
    assert ours.low == pytest.approx(ci["x"][0, 0], abs=0.01)
    assert ours.high == pytest.approx(ci["x"][1, 0], abs=0.01)
    pairs = {"x,y": (x, y)}
    _, ci = library.get_interval_estimates(
        pairs, metrics.probability_of_improvement, reps=5_000,
        random_state=np.random.RandomState(0),
    )  # fmt: skip
    ours = stats.probability_of_improvement(x, y, reps=5_000)
    assert ours.low == pytest.approx(ci["x,y"][0], abs=0.02)
    assert ours.high == pytest.approx(ci["x,y"][1], abs=0.02)


def test_seeds_and_episodes_interval_reduces_to_the_t_interval_of_the_factor_that_varies():
    rng = np.random.default_rng(3)
    episodes = (rng.random(40) < 0.6).astype(float)
    same_episodes = np.tile(episodes, (16, 1))  # every agent succeeds on the same episodes
    got = stats.seeds_and_episodes_interval(same_episodes)
    want = stats.t_interval(episodes)  # the episodes are the only sample
    assert got.estimate == pytest.approx(want.estimate) and got.n == 16
    assert (got.low, got.high) == pytest.approx((want.low, want.high), rel=1e-9)
    seeds = rng.random(12)
    same_seeds = np.tile(seeds[:, None], (1, 30))  # each agent scores the same on every one
    got, want = stats.seeds_and_episodes_interval(same_seeds), stats.t_interval(seeds)
    assert (got.low, got.high) == pytest.approx((want.low, want.high), rel=1e-9)


def test_seeds_and_episodes_interval_drops_diverged_rows_and_needs_two_of_each():
    y = np.array([[1.0, 0.0, 1.0], [np.nan] * 3, [0.0, 0.0, 1.0], [1.0, 1.0, 1.0]])
    assert stats.seeds_and_episodes_interval(y).n == 3
    assert stats.seeds_and_episodes_interval(y[:, :2]).estimate == pytest.approx(0.5)
    assert math.isnan(stats.seeds_and_episodes_interval(y[:1]).high)
    assert math.isnan(stats.seeds_and_episodes_interval(y[:, :1]).high)


@pytest.mark.parametrize(
    ("seed_sd", "episode_sd", "seeds_only_below"),
    [(0.3, 1.5, 0.75), (0.5, 0.0, 1.0)],  # episodes that matter / that do not
)
def test_seeds_and_episodes_interval_covers_the_mean_over_new_seeds_and_episodes(
    seed_sd, episode_sd, seeds_only_below
):
    """Successes of 16 agents on 50 shared episodes: 1{z_seed + w_episode + noise > -0.5},
    all normal, so the true success rate is Φ(0.5 / √(σ_z² + σ_w² + 1)). Over 400 tables
    (a fixed generator: the same counts on any CPU) the interval holds it 95 % of the time;
    the seeds' t interval, which holds the episodes fixed, far less where they matter."""
    from scipy.stats import norm

    truth = norm.cdf(0.5 / math.sqrt(seed_sd**2 + episode_sd**2 + 1))
    rng = np.random.default_rng(7)
    both = seeds_only = 0
    for _ in range(400):
        z, w = rng.normal(0, seed_sd, (16, 1)), rng.normal(0, episode_sd, (1, 50))
        y = (z + w + rng.normal(0, 1, (16, 50)) > -0.5).astype(float)
        iv, t = stats.seeds_and_episodes_interval(y), stats.t_interval(y.mean(axis=1))
        both += iv.low <= truth <= iv.high
        seeds_only += t.low <= truth <= t.high
    assert 0.92 <= both / 400 <= 0.98
    assert seeds_only / 400 < seeds_only_below


def test_seeds_and_episodes_interval_is_never_narrower_than_the_seeds_alone():
    """With 3 seeds the episodes' degrees of freedom can shrink the t quantile faster than
    their variance grows; the interval then keeps the seeds' t interval."""
    rng = np.random.default_rng(11)
    for _ in range(50):
        y = (rng.random((3, 30)) < rng.random((3, 1))).astype(float)
        both, seeds = stats.seeds_and_episodes_interval(y), stats.t_interval(y.mean(axis=1))
        assert both.half >= seeds.half - 1e-12
