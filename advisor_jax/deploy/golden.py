"""The golden set of an export: observations the runner must reproduce the JAX actions on.

The exporter's caller supplies rollout observations (``evaluation.evaluate.
rollout_observations``); to them we add hand-made corner cases and, up to ``MIN_GOLDEN``
rows, seeded random observations in the valid ranges.
"""

from __future__ import annotations

import math
from typing import Any

import numpy as np

from advisor_jax.contract import spec

MIN_GOLDEN = 256


class ExportError(ValueError):
    """Bad export inputs, a missing optional dependency, or a failed parity check."""


def edge_case_observations(max_range: float = spec.MAX_RANGE) -> np.ndarray:
    """[K, 20] float32 corner cases: saturated/empty zones, δ = ±π, d = 0 and far, fast."""
    rows = []

    def row(p, delta=0.3, d=2.0, vx=0.0, vy=0.0):
        rows.append(list(np.broadcast_to(np.asarray(p, np.float64), (16,))) + [delta, d, vx, vy])

    pi_below = float(np.nextafter(np.float32(math.pi), np.float32(0)))
    row(max_range)  # nothing in sight
    row(0.0)  # touching everywhere
    for delta in (-math.pi, math.pi, pi_below, -pi_below, 0.0, math.pi / 2, -math.pi / 2):
        row(max_range, delta=delta, d=3.0)
    for d in (0.0, 1e-3, 10.0, 50.0):
        row(max_range, d=d)
    for vx, vy in ((5.0, 5.0), (-5.0, 5.0), (10.0, -10.0), (-20.0, 0.0), (0.0, 20.0)):
        row(0.5 * max_range, delta=-1.0, vx=vx, vy=vy)
    for k in range(16):  # one close zone at a time: catches a permuted/transposed layout
        p = np.full(16, max_range)
        p[k] = 0.05 * max_range
        row(p, delta=math.pi * (k / 8.0 - 1.0), d=0.5 + 0.25 * k)
    left = np.where(np.arange(16) < 8, 0.1, max_range) * np.linspace(1.0, 0.5, 16)
    row(left, delta=pi_below, d=10.0, vx=-3.0, vy=2.0)  # mixed
    row(left[::-1], delta=-math.pi, d=0.0, vx=3.0, vy=-2.0)
    return np.asarray(rows, dtype=np.float32)


def _rollout_like(n: int, max_range: float, key: int = 0) -> np.ndarray:
    rng = np.random.default_rng(key)
    p = np.minimum(rng.uniform(0.0, 1.4 * max_range, (n, 16)), max_range)
    delta = rng.uniform(-math.pi, math.pi, (n, 1))
    d = rng.uniform(0.0, 7.0, (n, 1))
    v = rng.normal(0.0, 0.5, (n, 2))
    return np.concatenate([p, delta, d, v], axis=1).astype(np.float32)


def golden_observations(golden_obs: Any, max_range: float) -> np.ndarray:
    obs = np.asarray(golden_obs, dtype=np.float32)
    if obs.ndim != 2 or obs.shape[1] != spec.OBS_SIZE:
        raise ExportError(f"golden_obs must have shape [N, {spec.OBS_SIZE}], got {list(obs.shape)}")
    if not np.isfinite(obs).all():
        raise ExportError("golden_obs contains NaN or inf")
    obs = np.concatenate([obs, edge_case_observations(max_range)])
    fill = max(0, MIN_GOLDEN - len(obs))
    return np.concatenate([obs, _rollout_like(fill, max_range)]) if fill else obs
