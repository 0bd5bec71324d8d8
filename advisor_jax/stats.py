"""Statistics of seeds: the one place every report takes its intervals and comparisons from.

Scores are per seed (one agent's evaluation success, say). For a point of a study:

* ``t_interval``: mean and the half-width of the Student-t 95 % interval over seeds; shown
  only from ``MIN_SEEDS_FOR_INTERVAL`` seeds on (``format_interval``), since with two seeds
  the interval is mostly the t quantile (12.7).
* ``iqm`` and ``iqm_interval``: the interquartile mean (25 % trimmed mean, pooled over runs
  and tasks) with a percentile interval of the stratified bootstrap (runs resampled within
  each task), as in rliable (Agarwal et al., "Deep RL at the Edge of the Statistical
  Precipice", NeurIPS 2021; ``rliable.metrics.aggregate_iqm``,
  ``rliable.library.StratifiedBootstrap``, ``get_interval_estimates(method="percentile")``).
* ``probability_of_improvement``: P(X > Y) + ½ P(X = Y) over all pairs of runs, averaged over
  tasks (rliable's Mann-Whitney form), with an interval from resampling X's and Y's runs
  independently (``StratifiedIndependentBootstrap``).
* ``paired_difference``: X − Y seed by seed over the seeds both have (a seed fixes the
  initial networks and the environment stream; with one evaluation seed, the evaluation
  episodes too), its t interval and a verdict.
* ``welch_interval``: X − Y by means with Welch's interval, where no seeds are shared.
* ``seeds_and_episodes_interval``: the mean of a seeds × episodes table of scores with an
  interval for drawing both anew (``t_interval`` of the seeds' means holds the episodes
  fixed: every agent is scored on the same ones).

A "task" here is an evaluation arena: scores of shape [runs] are one task, [runs, tasks]
several. Bootstraps are seeded, so a report reproduces to the digit.
"""

from __future__ import annotations

import math
from collections.abc import Callable, Mapping, Sequence
from typing import NamedTuple

import numpy as np

LEVEL = 0.95
MIN_SEEDS_FOR_INTERVAL = 3
BOOTSTRAP_REPS = 10_000
BOOTSTRAP_SEED = 0


class Interval(NamedTuple):
    """An estimate, its interval [low, high] and the seeds it rests on (NaN: undefined)."""

    estimate: float
    low: float
    high: float
    n: int

    @property
    def half(self) -> float:
        """Half-width of a symmetric interval (the t interval's ±)."""
        return (self.high - self.low) / 2


def finite(values: Sequence[float | None] | np.ndarray) -> np.ndarray:
    """The finite values as float64 (None and NaN, e.g. a diverged seed, left out)."""
    x = np.asarray([np.nan if v is None else v for v in np.ravel(values)], np.float64)
    return x[np.isfinite(x)]


def t_interval(values: Sequence[float | None], level: float = LEVEL) -> Interval:
    """Mean and Student-t interval of the finite ``values`` (half-width NaN below 2)."""
    x = finite(values)
    if x.size == 0:
        return Interval(math.nan, math.nan, math.nan, 0)
    mean = float(x.mean())
    if x.size == 1:
        return Interval(mean, math.nan, math.nan, 1)
    from scipy import stats

    half = float(stats.t.ppf(0.5 + level / 2, x.size - 1) * x.std(ddof=1) / math.sqrt(x.size))
    return Interval(mean, mean - half, mean + half, int(x.size))


def format_interval(iv: Interval, scale: float = 1.0, digits: int = 1) -> str:
    """``"84.5 ± 4.8"``; below ``MIN_SEEDS_FOR_INTERVAL`` seeds the mean and ``(n=2)``."""
    if iv.n == 0 or math.isnan(iv.estimate):
        return "–"
    mean = f"{scale * iv.estimate:.{digits}f}"
    if iv.n < MIN_SEEDS_FOR_INTERVAL or math.isnan(iv.half):
        return f"{mean} (n={iv.n})"
    return f"{mean} ± {scale * iv.half:.{digits}f}"


def _trimmed_mean(x: np.ndarray) -> np.ndarray:
    """25 % trimmed mean over the last axis (``scipy.stats.trim_mean``'s cut: int(n / 4)
    values off each end of the sorted sample)."""
    n = x.shape[-1]
    cut = int(0.25 * n)
    return np.sort(x, axis=-1)[..., cut : n - cut].mean(axis=-1)


def iqm(scores: np.ndarray | Sequence[float]) -> float:
    """Interquartile mean of every score, runs and tasks pooled (rliable's
    ``aggregate_iqm``)."""
    x = np.asarray(scores, np.float64).ravel()
    return float(_trimmed_mean(x)) if x.size else math.nan


def _as_runs_by_tasks(scores) -> np.ndarray:
    x = np.asarray(scores, np.float64)
    return x[:, None] if x.ndim == 1 else x


def stratified_resamples(runs: int, tasks: int, reps: int, rng: np.random.Generator) -> np.ndarray:
    """Run indices [reps, runs, tasks]: each task's runs drawn with replacement from its
    own runs (the stratified bootstrap)."""
    return rng.integers(0, runs, size=(reps, runs, tasks))


def bootstrap_interval(
    scores,
    statistic: Callable[[np.ndarray], np.ndarray],
    reps: int = BOOTSTRAP_REPS,
    level: float = LEVEL,
    seed: int = BOOTSTRAP_SEED,
) -> Interval:
    """``statistic`` of ``scores`` [runs] or [runs, tasks] and its percentile interval over
    stratified bootstrap resamples; ``statistic`` maps [..., runs, tasks] to [...]."""
    x = _as_runs_by_tasks(scores)
    x = x[np.all(np.isfinite(x), axis=1)]
    if x.shape[0] == 0:
        return Interval(math.nan, math.nan, math.nan, 0)
    estimate = float(statistic(x[None])[0])
    if x.shape[0] < 2:
        return Interval(estimate, math.nan, math.nan, x.shape[0])
    idx = stratified_resamples(*x.shape, reps, np.random.default_rng(seed))
    samples = statistic(np.take_along_axis(x[None], idx, axis=1))
    low, high = np.percentile(samples, [50 * (1 - level), 50 * (1 + level)])
    return Interval(estimate, float(low), float(high), x.shape[0])


def iqm_interval(scores, reps: int = BOOTSTRAP_REPS, seed: int = BOOTSTRAP_SEED) -> Interval:
    """The IQM and its 95 % stratified-bootstrap percentile interval."""

    def statistic(x: np.ndarray) -> np.ndarray:  # [reps, runs, tasks] -> [reps]
        return _trimmed_mean(x.reshape(x.shape[0], -1))

    return bootstrap_interval(scores, statistic, reps=reps, seed=seed)


def _improvement(x: np.ndarray, y: np.ndarray) -> np.ndarray:
    """P(X > Y) + ½ P(X = Y) per resample, averaged over tasks: x [..., nx, tasks], y [...,
    ny, tasks] -> [...]."""
    gt = (x[..., :, None, :] > y[..., None, :, :]).mean(axis=(-3, -2))
    eq = (x[..., :, None, :] == y[..., None, :, :]).mean(axis=(-3, -2))
    return (gt + 0.5 * eq).mean(axis=-1)


def probability_of_improvement(
    x, y, reps: int = BOOTSTRAP_REPS, level: float = LEVEL, seed: int = BOOTSTRAP_SEED
) -> Interval:
    """P(X > Y) (ties count ½) over all pairs of X's and Y's runs, averaged over tasks, and
    its percentile interval with X's and Y's runs resampled independently within each task.
    ``n`` is the smaller run count."""
    a, b = (_as_runs_by_tasks(s) for s in (x, y))
    a, b = (s[np.all(np.isfinite(s), axis=1)] for s in (a, b))
    n = int(min(a.shape[0], b.shape[0]))
    if n == 0:
        return Interval(math.nan, math.nan, math.nan, 0)
    estimate = float(_improvement(a, b))
    if n < 2:
        return Interval(estimate, math.nan, math.nan, n)
    rng = np.random.default_rng(seed)
    samples = np.empty(reps)
    for start in range(0, reps, 1000):  # [block, runs, runs, tasks] stays small
        k = min(1000, reps - start)
        ia = stratified_resamples(*a.shape, k, rng)
        ib = stratified_resamples(*b.shape, k, rng)
        ra = np.take_along_axis(a[None], ia, axis=1)
        rb = np.take_along_axis(b[None], ib, axis=1)
        samples[start : start + k] = _improvement(ra, rb)
    low, high = np.percentile(samples, [50 * (1 - level), 50 * (1 + level)])
    return Interval(estimate, float(low), float(high), n)


class Paired(NamedTuple):
    """X − Y seed by seed: the seeds, the differences, their t interval and the verdict."""

    seeds: list
    differences: list[float]
    interval: Interval
    verdict: str


def verdict(iv: Interval, better: str = "above") -> str:
    """``holds`` when the interval lies on the ``better`` side of 0 ("above" or "below"),
    ``reversed`` on the other, else ``not resolved``."""
    if iv.n < 2 or math.isnan(iv.half):
        return "not resolved"
    above, below = iv.low > 0, iv.high < 0
    if better == "below":
        above, below = below, above
    return "holds" if above else "reversed" if below else "not resolved"


def paired_difference(
    x: Mapping[int, float | None], y: Mapping[int, float | None], better: str = "above"
) -> Paired | None:
    """X − Y over the seeds where both have a finite value; None below 2 such seeds."""
    seeds = [
        s
        for s in sorted(set(x) & set(y))
        if x[s] is not None and y[s] is not None and np.isfinite(x[s]) and np.isfinite(y[s])
    ]
    if len(seeds) < 2:
        return None
    diffs = [float(x[s]) - float(y[s]) for s in seeds]
    iv = t_interval(diffs)
    return Paired(seeds, diffs, iv, verdict(iv, better))


def welch_interval(x: Sequence[float | None], y: Sequence[float | None]) -> Interval:
    """mean(X) − mean(Y) and Welch's 95 % interval (unpaired; NaN half-width below 2 each)."""
    a, b = finite(x), finite(y)
    if a.size == 0 or b.size == 0:
        return Interval(math.nan, math.nan, math.nan, 0)
    diff = float(a.mean() - b.mean())
    n = int(min(a.size, b.size))
    if n < 2:
        return Interval(diff, math.nan, math.nan, n)
    va, vb = a.var(ddof=1) / a.size, b.var(ddof=1) / b.size
    if va + vb == 0:
        return Interval(diff, diff, diff, n)
    from scipy import stats

    df = (va + vb) ** 2 / (va**2 / (a.size - 1) + vb**2 / (b.size - 1))
    half = float(stats.t.ppf(0.5 + LEVEL / 2, df) * math.sqrt(va + vb))
    return Interval(diff, diff - half, diff + half, n)


def seeds_and_episodes_interval(scores: np.ndarray, level: float = LEVEL) -> Interval:
    """Mean of ``scores`` [seeds, episodes] (one agent per row, every agent on the same
    episodes) and its interval where the seeds *and* the episodes are random draws: the
    two-way crossed random-effects model y = μ + a_seed + b_episode + e, whose grand mean has
    variance σ_a²/S + σ_b²/E + σ_e²/(S E), estimated by (MS_seeds + MS_episodes −
    MS_residual) / (S E) from the mean squares of the two-way table (each expectation:
    σ_e² + E σ_a², σ_e² + S σ_b², σ_e²; a component estimated below 0 counts as 0), with
    Satterthwaite's degrees of freedom for the t quantile, and never narrower than
    ``t_interval`` of the row means, which is this with the episodes held fixed. Rows with a
    NaN (a diverged agent) are dropped; NaN half-width below 2 seeds or 2 episodes."""
    y = np.asarray(scores, np.float64)
    y = y[~np.isnan(y).any(axis=1)] if y.ndim == 2 else y.reshape(0, 0)
    n_seeds, n_episodes = y.shape if y.size else (0, 0)
    if n_seeds == 0 or n_episodes == 0:
        return Interval(math.nan, math.nan, math.nan, n_seeds)
    mean = float(y.mean())
    if n_seeds < 2 or n_episodes < 2:
        return Interval(mean, math.nan, math.nan, n_seeds)
    rows, cols = y.mean(axis=1), y.mean(axis=0)
    ms_seeds = n_episodes * float(np.sum((rows - mean) ** 2)) / (n_seeds - 1)
    ms_episodes = n_seeds * float(np.sum((cols - mean) ** 2)) / (n_episodes - 1)
    residual = y - rows[:, None] - cols[None, :] + mean
    ms_residual = float(np.sum(residual**2)) / ((n_seeds - 1) * (n_episodes - 1))
    # A variance component estimated below 0 counts as 0: its mean square drops out with
    # the residual's share it would cancel.
    terms = [(ms_residual, (n_seeds - 1) * (n_episodes - 1), 1.0)]  # (MS, its dof, weight)
    for ms, dof in ((ms_seeds, n_seeds - 1), (ms_episodes, n_episodes - 1)):
        if ms > ms_residual:
            terms += [(ms, dof, 1.0), (ms_residual, terms[0][1], -1.0)]
    combined = sum(w * ms for ms, _, w in terms)
    variance = combined / (n_seeds * n_episodes)
    if variance <= 0.0:
        return Interval(mean, mean, mean, n_seeds)
    dof = combined**2 / sum((w * ms) ** 2 / d for ms, d, w in terms)
    from scipy import stats

    half = float(stats.t.ppf(0.5 + level / 2, dof) * math.sqrt(variance))
    # Never narrower than with the episodes held fixed: more degrees of freedom from the
    # episodes' term can shrink the t quantile faster than the variance grows (3 seeds).
    half = max(half, t_interval(rows, level).half)
    return Interval(mean, mean - half, mean + half, n_seeds)


def summary(values: Sequence[float | None]) -> dict:
    """The numbers a report gives for one point's per-seed scores: mean and t interval,
    IQM and its bootstrap interval, worst and best seed, seed count (NaN → None in JSON)."""
    x = finite(values)
    t, q = t_interval(x), iqm_interval(x)
    return {
        "seeds": int(x.size),
        "mean": t.estimate,
        "ci95": [t.low, t.high],
        "iqm": q.estimate,
        "iqm_ci95": [q.low, q.high],
        "min": float(x.min()) if x.size else math.nan,
        "max": float(x.max()) if x.size else math.nan,
    }
