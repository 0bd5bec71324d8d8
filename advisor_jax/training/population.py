"""Populations: a grid of hyperparameters × seeds as one stacked ``HParams``.

Every agent of a population shares the static ``TrainConfig`` and differs only in scalar
hyperparameters and its seed, so the whole population is one ``vmap`` and one compile:

    hp, agents = build_population(HParams(), {"advisor_episodes": [100, 250]}, seeds=[0, 1, 2])
    # 6 agents: (N_T=100, seed 0), (100, 1), (100, 2), (250, 0), ...
"""

from __future__ import annotations

import dataclasses
import itertools
from collections.abc import Mapping, Sequence

import jax
import jax.numpy as jnp
import numpy as np

from advisor_jax.agent.config import HPARAM_NAMES, HParams, validate_hparams


def parse_assignments(items: Sequence[str]) -> dict[str, list[float]]:
    """``["beta=0.01,0.1", "gamma=0.9"]`` → ``{"beta": [0.01, 0.1], "gamma": [0.9]}``."""
    grid: dict[str, list[float]] = {}
    for item in items:
        name, sep, values = item.partition("=")
        name = name.strip()
        if not sep or not values.strip():
            raise ValueError(f"expected NAME=V1[,V2,...], got {item!r}")
        if name not in HPARAM_NAMES:
            raise ValueError(
                f"unknown hyperparameter {name!r}; choose from {', '.join(HPARAM_NAMES)}"
            )
        try:
            grid[name] = [float(v) for v in values.split(",")]
        except ValueError:
            raise ValueError(f"non-numeric value in {item!r}") from None
    return grid


def build_population(
    base: HParams, grid: Mapping[str, Sequence[float]], seeds: Sequence[int]
) -> tuple[HParams, list[dict]]:
    """Cartesian product of ``grid`` (first key slowest) × ``seeds`` (fastest).

    Returns the stacked hyperparameters (every leaf float32 [agents]) and one row per agent:
    ``{"index", "seed", **hyperparameters}``.
    """
    if not seeds:
        raise ValueError("need at least one seed")
    for name, values in grid.items():
        if name not in HPARAM_NAMES:
            raise ValueError(f"unknown hyperparameter {name!r}")
        if len(values) == 0:
            raise ValueError(f"empty value list for {name!r}")
    names = list(grid)
    rows = []
    for values in itertools.product(*(grid[n] for n in names)):
        for seed in seeds:
            hp = dataclasses.replace(base, **dict(zip(names, values, strict=True)))
            rows.append({"seed": int(seed), **{n: float(getattr(hp, n)) for n in HPARAM_NAMES}})
    for i, row in enumerate(rows):
        row["index"] = i
    stacked = HParams(**{n: np.array([r[n] for r in rows], np.float32) for n in HPARAM_NAMES})
    validate_hparams(stacked)
    return jax.tree_util.tree_map(jnp.asarray, stacked), rows


def agent_keys(seeds: Sequence[int]) -> jax.Array:
    """One PRNG key per agent, from its seed alone (so a vmapped agent equals a lone run)."""
    return jnp.stack([jax.random.PRNGKey(int(s)) for s in seeds])


def index_population(hp: HParams, i: int) -> HParams:
    """The hyperparameters of agent ``i`` of a stacked population."""
    return jax.tree_util.tree_map(lambda x: x[i], hp)
