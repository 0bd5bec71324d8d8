"""Populations: a grid of hyperparameters × seeds as one stacked ``HParams``.

Every agent of a population shares the static ``TrainConfig`` and differs only in scalar
hyperparameters (an ``HParams``, or a baseline's ``BaselineHParams``, named flat) and its
seed, so the whole population is one ``vmap`` and one compile:

    hp, agents = build_population(HParams(), {"advisor_episodes": [100, 250]}, seeds=[0, 1, 2])
    # 6 agents: (N_T=100, seed 0), (100, 1), (100, 2), (250, 0), ...
"""

from __future__ import annotations

import itertools
import math
from collections.abc import Mapping, Sequence

import jax
import jax.numpy as jnp
import numpy as np

from advisor_jax.agent.hparams import HPARAM_NAMES
from advisor_jax.agent.settings import flat_fields, flat_items, from_flat, replace_flat, validate
from advisor_jax.training.limits import check_agents

SEED_MAX = 2**64 - 1
"""Seeds are 64-bit: ``seed_key`` puts both 32-bit halves into the threefry key."""


def parse_assignments(items: Sequence[str], option: str = "--hp/--grid") -> dict[str, list[float]]:
    """``["beta=0.01,0.1", "gamma=0.9"]`` → ``{"beta": [0.01, 0.1], "gamma": [0.9]}``.

    A name given twice is refused (naming ``option`` and both items) rather than silently
    keeping the last one, and so is a value listed twice for one name (``beta=0.1,0.1``
    would train identical agents as two grid points).
    """
    grid: dict[str, list[float]] = {}
    given: dict[str, str] = {}
    for item in items:
        name, sep, values = item.partition("=")
        name = name.strip()
        if not sep or not values.strip():
            syntax = {"--hp": "NAME=VALUE, e.g. --hp beta=0.1",
                      "--grid": "NAME=V1,V2,..., e.g. --grid beta=0.01,0.1"}  # fmt: skip
            raise ValueError(f"{option} expects {syntax.get(option, 'NAME=V1[,V2,...]')}, "
                             f"got {item!r}")  # fmt: skip
        if name not in HPARAM_NAMES:
            raise ValueError(
                f"unknown hyperparameter {name!r}; choose from {', '.join(HPARAM_NAMES)}"
            )
        if name in given:
            raise ValueError(
                f"{option} sets {name} twice ({given[name]!r} and {item!r}); give it once"
            )
        given[name] = item
        try:
            grid[name] = [float(v) for v in values.split(",")]
        except ValueError:
            raise ValueError(f"non-numeric value in {item!r}") from None
        twice = sorted({v for v in grid[name] if grid[name].count(v) > 1})
        if twice:
            raise ValueError(
                f"{option} {item!r} lists {', '.join(f'{v:g}' for v in twice)} more than once: "
                "those grid points would train identical agents; give each value once"
            )
    return grid


def build_population(
    base,
    grid: Mapping[str, Sequence[float]],
    seeds: Sequence[int],
    points: Sequence[Mapping[str, float]] | None = None,
) -> tuple[object, list[dict]]:
    """Cartesian product of ``grid`` (first key slowest) × ``seeds`` (fastest).

    ``base``: the agent type's hyperparameters (``HParams`` or ``BaselineHParams``); the
    grid names them flat. ``points``: the grid points to train, each ``{name: value}`` over
    exactly ``grid``'s names, in place of the product of ``grid``'s values (a study's piece
    holds a subset of points, or points whose values depend on each other). Returns the
    stacked hyperparameters (every leaf float32 [agents]) and one row per agent:
    ``{"index", "seed", **hyperparameters}`` (flat names).
    """
    if not seeds:
        raise ValueError("need at least one seed")
    fields = flat_fields(base)
    for name, values in grid.items():
        if name not in fields:
            raise ValueError(f"unknown hyperparameter {name!r}")
        if len(values) == 0:
            raise ValueError(f"empty value list for {name!r}")
        if len(set(map(float, values))) != len(values):
            raise ValueError(f"a value of {name!r} is listed twice in the grid: {list(values)}")
    n_points = len(points) if points is not None else math.prod(len(v) for v in grid.values())
    check_agents(len(seeds) * n_points)
    if len(set(seeds)) != len(seeds):
        raise ValueError(f"a seed is listed twice: {list(seeds)}")
    for seed in seeds:
        check_seed(seed)
    names = list(grid)
    combos = list(itertools.product(*(grid[n] for n in names)))
    if points is not None:
        for point in points:
            if set(point) != set(names):
                raise ValueError(f"grid point {dict(point)} must set exactly {names}")
        combos = [tuple(point[n] for n in names) for point in points]
        if not combos:
            raise ValueError("need at least one grid point")
    rows = []
    for values in combos:
        for seed in seeds:
            hp = replace_flat(base, **dict(zip(names, values, strict=True)))
            flat = {n: float(v) for n, v in flat_items(hp).items()}
            rows.append({"seed": int(seed), **flat})
    for i, row in enumerate(rows):
        row["index"] = i
    stacked = from_flat(base, {n: np.array([r[n] for r in rows], np.float32) for n in fields})
    validate(stacked)
    return jax.tree_util.tree_map(jnp.asarray, stacked), rows


def check_seed(seed: int, what: str = "seed") -> int:
    """``seed`` as an int, or ValueError naming it and the allowed range [0, 2^64 - 1]."""
    if isinstance(seed, bool) or not isinstance(seed, int | np.integer):
        raise ValueError(f"{what} {seed!r} must be an integer in [0, 2^64 - 1]")
    seed = int(seed)
    if not 0 <= seed <= SEED_MAX:
        raise ValueError(f"{what} {seed} is out of range: seeds are integers in [0, 2^64 - 1]")
    return seed


def seed_key(seed: int) -> jax.Array:
    """The raw threefry key ``[seed >> 32, seed & 0xFFFFFFFF]`` (uint32[2]) of a 64-bit seed.

    ``jax.random.PRNGKey(seed)`` with 64-bit types disabled (the default) keeps only the low
    32 bits, so seed 2^40 gave seed 0's key, and seeds >= 2^63 raised OverflowError. This is
    what PRNGKey computes for seeds in [0, 2^32) (tests/train checks it), so every result
    seeded there reproduces bit for bit, and it is injective over [0, 2^64).
    """
    seed = check_seed(seed)
    return jnp.asarray(np.array([seed >> 32, seed & 0xFFFFFFFF], dtype=np.uint32))


def eval_key(eval_seed: int) -> jax.Array:
    """The key of a run's evaluation episodes (run.json ``eval_seed``): the key of seed
    10,000 + ``eval_seed`` (mod 2^64), so evaluation episodes are not a training seed's."""
    return seed_key((10_000 + check_seed(eval_seed, "eval_seed")) % (SEED_MAX + 1))


def agent_keys(seeds: Sequence[int]) -> jax.Array:
    """One PRNG key per agent, from its seed alone (so a vmapped agent equals a lone run)."""
    return jnp.stack([seed_key(s) for s in seeds])


def index_population(hp, i: int):
    """The hyperparameters of agent ``i`` of a stacked population."""
    return jax.tree_util.tree_map(lambda x: x[i], hp)
