"""The training chunk's steady program (training/train.py, "Steady program").

GPUs run each chunk past warm-up as the same steps without a ``lax.cond`` inside: blocks of
d steps whose first takes the actor update. It must be chosen exactly when that is valid,
hold no conditional, only exist where it can, and compute the general program's steps: the
same counters, and parameters and metrics equal up to float rounding (the two programs fuse
differently, so bit-equality is not expected).
"""

from __future__ import annotations

import collections
import dataclasses

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from advisor_jax.agent.config import parse_agent
from advisor_jax.training import program
from advisor_jax.training.devices import Placement, place
from advisor_jax.training.population import agent_keys
from advisor_jax.training.program import (
    LATENCY_BOUND_AGENTS,
    LATENCY_BOUND_BF16_AGENTS,
    latency_bound,
    population_functions,
)
from advisor_jax.training.train import steady_at
from tests.training.conftest import GOOD, TINY, _population, primitive_names

ROUNDING = 1e-4
"""Largest ||general - steady|| / ||general|| accepted after one 40-step chunk (fp32): the
2-core Xeon VM measured ~1e-7; Adam turns rounding into step-size differences where
gradients are tiny, so the bound leaves room for other CPUs' rounding."""


def relative(a, b) -> float:
    """||a - b|| / ||a|| over a tree's leaves (L2), NaN entries (skipped steps) left out."""
    num = den = 0.0
    for x, y in zip(jax.tree.leaves(a), jax.tree.leaves(b), strict=True):
        x, y = np.asarray(x, np.float64), np.asarray(y, np.float64)
        assert np.array_equal(np.isnan(x), np.isnan(y))
        keep = ~np.isnan(x)
        num += float(np.sum((x[keep] - y[keep]) ** 2))
        den += float(np.sum(x[keep] ** 2))
    return (num / den) ** 0.5 if den else num


@pytest.fixture(scope="module")
def steady_functions():
    return population_functions(TINY, program="latency-bound")


@pytest.fixture(scope="module")
def after_first_chunk(tiny_functions):
    """The shared population's state after its first (warm-up) chunk, as numpy."""
    _, init_fn, chunk_fn = tiny_functions
    hp, seeds = _population()
    state, _ = chunk_fn(init_fn(agent_keys(seeds)), hp, jnp.int32(0))
    return jax.device_get(state), hp


def test_cpus_keep_the_general_program_by_default(tiny_functions, steady_functions):
    assert not tiny_functions[0].steady  # this suite runs on CPUs
    assert steady_functions[0].steady


def _placement(n_padded: int | None, n_devices: int) -> Placement | None:
    """A placement of ``n_padded`` agents on ``n_devices`` (None: an unknown population),
    with a stand-in mesh: the choice reads only its size."""

    class Mesh:
        size = n_devices

    if n_padded is None:
        return None
    return Placement(None if n_devices == 1 else Mesh(), n_padded, n_padded)


@pytest.mark.parametrize(
    ("n_padded", "n_devices", "backend", "expected"),
    [(1, 1, "gpu", True), (LATENCY_BOUND_AGENTS, 1, "gpu", True),
     (LATENCY_BOUND_AGENTS + 1, 1, "gpu", False),
     (2 * LATENCY_BOUND_AGENTS, 2, "gpu", True),  # per device
     (1, 1, "cpu", False), (None, 1, "gpu", False)],  # unknown population: not latency-bound
)  # fmt: skip
def test_only_small_populations_on_gpus_are_latency_bound(n_padded, n_devices, backend, expected):
    assert latency_bound(_placement(n_padded, n_devices), backend) == expected


@pytest.mark.parametrize(
    ("n_padded", "n_devices", "expected"),
    [(LATENCY_BOUND_BF16_AGENTS, 1, True), (LATENCY_BOUND_BF16_AGENTS + 1, 1, False),
     (2 * LATENCY_BOUND_BF16_AGENTS, 2, True), (2 * LATENCY_BOUND_BF16_AGENTS + 2, 2, False)],
)  # fmt: skip
def test_bf16_populations_are_latency_bound_up_to_their_own_size(n_padded, n_devices, expected):
    placement = _placement(n_padded, n_devices)
    assert LATENCY_BOUND_BF16_AGENTS > LATENCY_BOUND_AGENTS
    assert latency_bound(placement, "gpu", "bf16") == expected
    assert not latency_bound(placement, "cpu", "bf16")


@pytest.mark.parametrize(
    ("n_padded", "n_devices", "backend", "expected"),
    [(LATENCY_BOUND_AGENTS, 1, "gpu", "latency-bound"),
     (LATENCY_BOUND_AGENTS + 1, 1, "gpu", "general"),  # one GPU, fp32: the general program
     (2 * LATENCY_BOUND_AGENTS, 2, "gpu", "latency-bound"),
     (2 * LATENCY_BOUND_AGENTS + 2, 2, "gpu", "steady"),  # sharded: no all-gathers in the loop
     (512, 4, "gpu", "steady"),
     (512, 4, "cpu", "general"), (1, 1, "cpu", "general"),  # CPUs keep their results
     (None, 1, "gpu", "general")],
)  # fmt: skip
def test_the_program_is_chosen_from_the_population_and_its_devices(
    n_padded, n_devices, backend, expected
):
    assert program.choose_program(_placement(n_padded, n_devices), backend) == expected


def test_a_request_resolves_to_the_program_that_runs():
    placement = _placement(48, 1)
    for name in program.PROGRAMS:  # named: as asked, whatever the population
        assert program.resolve_program(name, placement, "bf16") == name
    for request in ("auto", None):  # auto: choose_program's pick on JAX's default backend
        assert program.resolve_program(request, placement, "bf16") == program.choose_program(
            placement, precision="bf16"
        )
    with pytest.raises(ValueError, match="program 'fast': not one of"):
        program.resolve_program("fast", placement)


H100 = int(0.75 * 81559 * 2**20)  # what JAX may allocate of an H100 80GB by default


@pytest.mark.parametrize(
    ("n_padded", "precision", "memory_bytes", "expected"),
    [(LATENCY_BOUND_BF16_AGENTS + 1, "bf16", H100, "steady"),  # measured faster, fits
     (512, "bf16", H100, "steady"),
     (LATENCY_BOUND_AGENTS, "bf16", H100, "latency-bound"),
     (LATENCY_BOUND_BF16_AGENTS, "bf16", H100, "latency-bound"),
     (1024, "bf16", H100, "general"),  # would not fit: the general program's largest stays
     (256, "bf16", int(0.75 * 24e9), "general"),  # a 24 GB card: the general one's 16 GiB
     (64, "fp32", H100, "general"),  # fp32: the steady program was slower
     (LATENCY_BOUND_BF16_AGENTS + 1, "bf16", None, "general")],  # memory unknown (CPU devices)
)  # fmt: skip
def test_one_gpus_bf16_population_gets_the_steady_program_where_its_memory_holds_it(
    n_padded, precision, memory_bytes, expected
):
    placement = _placement(n_padded, 1)
    assert program.choose_program(placement, "gpu", precision, memory_bytes) == expected
    assert program.choose_program(placement, "cpu", precision, memory_bytes) == "general"


@pytest.mark.parametrize(
    ("first_step", "n_envs", "expected"),
    [(0, 1, False), (30, 1, False),  # the buffer holds < 32 transitions before the first step
     (31, 1, False),  # 31 before it: step 31 draws from 31 (its own is stored after the draw)
     (33, 1, False),  # past warm-up, but the first step is not a block head (d = 2)
     (32, 1, True), (40, 1, True), (41, 1, False),
     (15, 2, False), (16, 2, True)],  # two envs: 32 transitions before step 16
)  # fmt: skip
def test_steady_exactly_when_past_warmup_and_on_a_block_head(first_step, n_envs, expected):
    assert steady_at(first_step, n_envs, warmup=32, delay=2) == expected
    assert steady_at(jnp.int32(first_step), n_envs, 32, 2) == expected  # traced as in chunk


def test_the_steady_program_holds_no_conditional(steady_functions):
    trainer = steady_functions[0]
    hp, seeds = _population()
    state = jax.eval_shape(jax.vmap(trainer.init), agent_keys(seeds))
    chunk = jax.vmap(trainer.chunk, in_axes=(0, 0, None))
    jaxpr = jax.make_jaxpr(chunk)(state, hp, jnp.int32(0)).jaxpr
    (top,) = [e for e in jaxpr.eqns if e.primitive.name == "cond"]  # one per chunk
    general, steady = (collections.Counter(primitive_names(b.jaxpr))
                       for b in top.params["branches"])  # fmt: skip
    assert general["cond"] >= 2  # the warm-up gate and the actor delay
    assert steady["cond"] == 0
    assert steady["scan"] == 1 + TINY.agent.delay  # the block loop and each step's updates


@pytest.mark.parametrize(
    ("overrides", "built"),
    [(dict(), True),
     (dict(chunk_steps=41), False),  # not a whole number of delay periods
     (dict(updates_per_step=2), False),  # the actor's updates would move within the step
     (dict(updates_per_step=2, agent=parse_agent("DDPG", batch_size=32)), True),  # no delay
     (dict(agent=parse_agent("LfD", batch_size=32)), False)],  # a baseline's phases
)  # fmt: skip
def test_the_steady_program_is_built_only_where_it_exists(overrides, built):
    cfg = dataclasses.replace(TINY, **overrides)
    assert population_functions(cfg, program="steady")[0].steady == built
    assert population_functions(cfg, program="latency-bound")[0].steady == built
    assert not population_functions(cfg, program="general")[0].steady


@pytest.mark.parametrize("first_step", [40, 41, 0])  # steady; general past warm-up; warm-up
def test_a_chunk_computes_the_general_programs_steps(
    tiny_functions, steady_functions, after_first_chunk, first_step
):
    """From the same state, one chunk of each program. At 41 the steady program would put
    the actor updates on the wrong steps (as many, one step late): the parameters would
    differ far beyond rounding (checked by breaking ``steady_at``)."""
    start, hp = after_first_chunk
    general_state, general_metrics = jax.device_get(
        tiny_functions[2](start, hp, jnp.int32(first_step))
    )
    steady_state, steady_metrics = jax.device_get(
        steady_functions[2](start, hp, jnp.int32(first_step))
    )
    g, s = general_state, steady_state
    np.testing.assert_array_equal(g.learner.critic_updates, s.learner.critic_updates)
    np.testing.assert_array_equal(g.learner.actor_updates, s.learner.actor_updates)
    np.testing.assert_array_equal(g.diverged, s.diverged)
    assert g.diverged.tolist() == [False] * GOOD + [True]
    healthy = lambda tree: jax.tree.map(lambda x: np.asarray(x)[:GOOD], tree)  # noqa: E731
    for part in ("actor", "critic", "target_actor", "target_critic"):
        assert (
            relative(healthy(getattr(g.learner, part)), healthy(getattr(s.learner, part)))
            < ROUNDING
        ), part
    for key in ("loss/critic", "q/mean", "loss/actor", "grad_norm/critic"):
        assert relative(healthy(general_metrics[key]), healthy(steady_metrics[key])) < ROUNDING, key
    np.testing.assert_array_equal(
        general_metrics["train/episodes"], steady_metrics["train/episodes"]
    )


def test_population_functions_pick_the_program_from_the_placement(monkeypatch):
    asked = []
    monkeypatch.setattr(program, "latency_bound", lambda p, b=None, _=None: asked.append(p) or True)
    trainer, _, _ = program.population_functions(TINY, place(3, 1))
    assert asked == [place(3, 1)] and trainer.steady  # as on a GPU
    assert not program.population_functions(TINY, place(3, 1), "general")[0].steady


def test_an_unknown_program_is_refused_by_name():
    with pytest.raises(ValueError, match="'stedy'"):
        program.population_functions(TINY, program="stedy")


class Built(Exception):
    """Raised by a stand-in ``population_functions``: the program was asked for."""


@pytest.mark.parametrize(("option", "expected"), [([], None), (["--program", "steady"], "steady")])
def test_train_program_reaches_the_built_program_and_run_json(
    tmp_path, monkeypatch, option, expected
):
    """``advisor-jax train --program P`` builds program P (auto: ``choose_program``'s, a
    CPU's general program). The CLI passes it as ``chunk_program`` only: ``run_training``
    records the program it builds in run.json, explicit or chosen
    (tests/training/test_run.py)."""
    from advisor_jax.cli.main import main as cli_main
    from advisor_jax.training import host_loop

    asked, real = [], host_loop.run_training

    def recording_run(*args, **kw):
        asked.append(kw.get("meta"))
        return real(*args, **kw)

    def built(cfg, placement, chunk_program=None):
        asked.append(chunk_program)
        raise Built

    monkeypatch.setattr(host_loop, "run_training", recording_run)
    monkeypatch.setattr(host_loop, "population_functions", built)
    with pytest.raises(Built):
        cli_main(["train", "--out", str(tmp_path / "run"), "--no-progress", *option])
    assert asked == [{"preset": "quick"}, expected or program.choose_program(None)]


def test_the_population_functions_pass_the_agents_per_device_to_the_layout(monkeypatch):
    """``population_functions`` asks ``program_layout`` with its placement's agents per device."""
    asked = []
    real = program.program_layout

    def spy(name, precision, backend=None, agents_per_device=None):
        asked.append(agents_per_device)
        return real(name, precision, backend, agents_per_device)

    monkeypatch.setattr(program, "program_layout", spy)
    program.population_functions(TINY, place(3, 1), "steady")
    program.population_functions(TINY, None, "steady")
    assert asked == [3, None]


def test_the_latency_bound_program_holds_networks_and_stores_as_its_agents_say(monkeypatch):
    """``population_functions`` has ``make_train`` hold the learner's networks as
    ``holds_networks`` says for its precision (bf16, at any size), and store with no barrier
    as ``stores_free`` says for its placement's agents per device: one agent per device."""
    held, free = [], []
    real = program.make_train

    def spy(cfg, steady, layout, hold, free_store):
        held.append(hold)
        free.append(free_store)
        return real(cfg, steady, layout, hold, free_store)

    monkeypatch.setattr(program, "make_train", spy)
    bf16 = dataclasses.replace(TINY, agent=dataclasses.replace(TINY.agent, precision="bf16"))
    for cfg, agents in [(bf16, 4), (bf16, 2), (TINY, 4), (bf16, 1), (TINY, 1)]:
        program.population_functions(cfg, place(agents, 1), "latency-bound")
    assert held == [True, True, False, True, False]
    assert free == [False, False, False, True, True]
    assert not program.stores_free("steady", 1) and not program.stores_free("latency-bound")
