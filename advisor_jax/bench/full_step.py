"""The full training step's speed: agent env-steps/s of a population's jitted chunk, placed
and started as training does (``training.devices``), timed past its warm-up.

One environment step of an agent = advisor + actor + Eq. 1 selector (2 critic calls) + OU
noise + env step + replay insert + ``updates_per_step`` updates (critic every step, actor
every d-th). ``experiments/bench_train.py`` tables it over populations, devices and
precisions; ``experiments/bench_peers.py`` sets it beside a peer's TD3.
"""

from __future__ import annotations

import dataclasses

import jax
import jax.numpy as jnp

from advisor_jax.agent.config import preset
from advisor_jax.bench import measure
from advisor_jax.training import program
from advisor_jax.training.devices import init_population, place, put
from advisor_jax.training.population import agent_keys, build_population

PROGRAMS = ("auto", *program.PROGRAMS)
"""``--program``: auto (as training picks it, ``program.choose_program``) or one of
``program.PROGRAMS``."""


def full_step(
    preset_name: str,
    agent: str,
    n: int,
    devices: int = 1,
    precision: str = "fp32",
    chunk: int = 500,
    repeats: int = 3,
    motion: str = "kinematic",
    chunk_program: str = "auto",
) -> dict:
    """Agent env-steps/s of ``n`` agents of ``agent`` at ``preset_name`` on ``devices``
    devices, the learner at ``precision``: best of ``repeats`` chunks of ``chunk`` steps
    after a warm-up (compile and the steps before the buffer holds a batch). The row names
    the program that ran (``chunk_program`` "auto": the one training picks)."""
    cfg, hp = preset(preset_name, agent, precision=precision)
    # Enough episodes that nobody finishes during the benchmark; warm-up past learning start.
    cfg = dataclasses.replace(cfg, chunk_steps=chunk, episodes=100_000, motion=motion)
    placement = place(n, devices)
    chunk_program = program.resolve_program(chunk_program, placement, precision)
    _, init_fn, chunk_fn = program.population_functions(cfg, placement, chunk_program)
    hp, _ = build_population(hp, {}, seeds=list(range(n)))
    hp = put(hp, placement)
    keys = agent_keys(list(range(n)))
    state, step = init_population(init_fn, keys, placement, cfg.episodes), 0  # as training

    def one_chunk():
        nonlocal state, step
        state, _ = chunk_fn(state, hp, jnp.int32(step))
        step += chunk
        return state

    def warm_up():  # compile + the first steps, before the buffer holds a batch
        while step * cfg.envs_per_agent < cfg.agent.warmup + chunk:
            one_chunk()
        return state

    _, warmup = measure.run_timed(warm_up)
    best = measure.best_of(one_chunk, repeats)
    stats = jax.devices()[0].memory_stats() or {}  # None on CPUs
    return dict(
        agents=n,
        devices=devices,
        precision=precision,
        program=chunk_program,
        agent_steps_per_s=n * chunk * cfg.envs_per_agent / best,
        seconds_per_chunk=best,
        warmup_s=warmup,
        # the process's peak so far (this row's population and every one timed before it)
        peak_gib=stats["peak_bytes_in_use"] / 2**30 if "peak_bytes_in_use" in stats else None,
    )
