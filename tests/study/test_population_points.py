"""``build_population(..., points=...)``: explicit grid points in place of the product."""

from __future__ import annotations

import numpy as np
import pytest

from advisor_jax.agent.config import HParams
from advisor_jax.training.population import build_population


def test_points_replace_the_product_and_seeds_stay_fastest():
    grid = {"eps_start": [0.5, 1.0], "eps_decay": [0.004, 0.002]}
    points = [{"eps_start": 0.5, "eps_decay": 0.004}, {"eps_start": 1.0, "eps_decay": 0.008}]
    hp, rows = build_population(HParams(), grid, [3, 4], points)
    assert [(r["eps_start"], r["eps_decay"], r["seed"]) for r in rows] == [
        (0.5, 0.004, 3), (0.5, 0.004, 4), (1.0, 0.008, 3), (1.0, 0.008, 4)
    ]  # fmt: skip
    np.testing.assert_allclose(hp.eps_decay, [0.004, 0.004, 0.008, 0.008], rtol=1e-6)
    assert [r["index"] for r in rows] == [0, 1, 2, 3]


def test_a_point_must_set_exactly_the_grid_names():
    with pytest.raises(ValueError, match="must set exactly"):
        build_population(HParams(), {"beta": [1.0]}, [0], [{"beta": 1.0, "tau": 0.1}])
    with pytest.raises(ValueError, match="out|outside"):
        build_population(HParams(), {"tau": [0.1]}, [0], [{"tau": 2.0}])
