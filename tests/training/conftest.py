"""Shared, compiled-once fixtures for the training tests.

One tiny ATD3+AfDP configuration is compiled twice per session: as a vmapped population
(``program.population_functions``, the program ``run_training`` runs) and as a single agent.
"""

from __future__ import annotations

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from advisor_jax.agent.config import HParams, TrainConfig, parse_agent
from advisor_jax.training.population import agent_keys, build_population
from advisor_jax.training.program import population_functions

TINY = TrainConfig(
    agent=parse_agent(
        "ATD3+AfDP",
        actor_hidden=(16, 16),
        critic_state_hidden=32,
        critic_hidden=(32, 32),
        buffer_size=512,
        batch_size=32,
        policy_delay=2,
    ),
    arena="training",
    episodes=3,
    chunk_steps=40,
    max_episode_steps=40,
    snapshot_episodes=(2,),  # every shared run also keeps its actor of episode 2
)
N_CHUNKS = 3  # 3 × 40 steps ≥ 3 episodes × h_max 40: every agent finishes
GOOD = 4  # agents 0..3 are healthy; agent 4 has an absurd critic learning rate


def _population():
    base = HParams(lr_actor=1e-3, advisor_episodes=1.0)
    hp, agents = build_population(base, {"beta": [0.01, 0.3]}, seeds=[0, 1])
    # A fifth agent that must diverge: Adam steps of 1e38 overflow the critic.
    bad = base.replace(lr_critic=1e38)
    hp = jax.tree_util.tree_map(lambda col, v: jnp.append(col, jnp.float32(v)), hp, bad)
    seeds = [a["seed"] for a in agents] + [0]
    return hp, seeds


def run_chunks(init_fn, chunk_fn, key, hp, n_chunks=N_CHUNKS, state=None, first=0):
    state = init_fn(key) if state is None else state
    for c in range(first, n_chunks):
        state, _ = chunk_fn(state, hp, jnp.int32(c * TINY.chunk_steps))
    return state


def primitive_names(jaxpr, found=None) -> list[str]:
    """Every primitive of a jaxpr, sub-jaxprs (scan, cond branches, ...) included."""
    found = [] if found is None else found
    for eqn in jaxpr.eqns:
        found.append(eqn.primitive.name)
        for value in eqn.params.values():
            for sub in value if isinstance(value, tuple | list) else [value]:
                inner = getattr(sub, "jaxpr", sub)
                if hasattr(inner, "eqns"):
                    primitive_names(inner, found)
    return found


def run_chunks_with_metrics(chunk_fn, state, hp, chunk_steps, first, last, gate_fn=None):
    """Chunks ``first`` .. ``last - 1`` from ``state``: (final state, the chunks' metrics
    concatenated along the step axis), both as numpy. With ``gate_fn`` ((state, hp) ->
    a baseline's population gate), the metrics also hold ``gate`` [chunks, phases + 1]:
    each chunk's gate, from the state it started from."""
    out, gates = [], []
    for c in range(first, last):
        if gate_fn is not None:  # before the chunk, which donates the state
            gates.append(np.asarray(gate_fn(state, hp)))
        state, metrics = chunk_fn(state, hp, jnp.int32(c * chunk_steps))
        out.append(jax.device_get(metrics))
    merged = {k: np.concatenate([np.asarray(m[k]) for m in out], axis=1) for k in out[0]}
    if gate_fn is not None:
        merged["gate"] = np.stack(gates)
    return jax.device_get(state), merged


def gate_function(cfg):
    """jit((state, hp) -> the population's gate), as ``population_functions`` computes it."""
    from advisor_jax.training.prior.trainer import make_prior_program

    return jax.jit(make_prior_program(cfg).population_gate)


def assert_gate_covers_play(metrics, chunk_steps) -> None:
    """Soundness in a run: every phase that some agent played at some step of a chunk had
    its gate on for that chunk (all agents real, none padding)."""
    phase, gate = metrics["train/phase"], metrics["gate"]
    for c in range(gate.shape[0]):
        played = np.unique(phase[:, c * chunk_steps : (c + 1) * chunk_steps])
        assert gate[c, played].all(), f"chunk {c}: played {played}, gate {gate[c]}"


@pytest.fixture(scope="session")
def tiny_functions():
    """(trainer, jit(vmap(init)), jit(vmap(chunk))) of TINY, compiled once per session."""
    return population_functions(TINY)


@pytest.fixture(scope="session")
def population(tiny_functions):
    """The final state of the 5-agent vmapped run, as numpy."""
    trainer, init_fn, chunk_fn = tiny_functions
    hp, seeds = _population()
    state = run_chunks(init_fn, chunk_fn, agent_keys(seeds), hp)
    return jax.device_get(state), hp, seeds


@pytest.fixture(scope="session")
def initial_state(population, tiny_functions):
    """The population's state before training (what ``population`` started from)."""
    _, init_fn, _ = tiny_functions
    return jax.device_get(init_fn(agent_keys(population[2])))


@pytest.fixture(scope="session")
def single_runs(population, tiny_functions):
    """The healthy agents run one by one with the unvmapped functions."""
    _, hp, seeds = population
    trainer = tiny_functions[0]
    init_fn, chunk_fn = jax.jit(trainer.init), jax.jit(trainer.chunk)
    out = []
    for i in range(GOOD):
        hp_i = jax.tree_util.tree_map(lambda x, i=i: x[i], hp)
        out.append(
            jax.device_get(run_chunks(init_fn, chunk_fn, jax.random.PRNGKey(seeds[i]), hp_i))
        )
    return out


def agent_slice(tree, i):
    return jax.tree_util.tree_map(lambda x: np.asarray(x)[i], tree)


# A TINY run through the host loop (run_training), as the CLI would run it ----------------

RUN_SEEDS = [0, 1, 2, 3, 4]
RUN_HP = HParams(lr_actor=1e-3, advisor_episodes=1.0)


def train_tiny(out, program, **kw):
    """A TINY run of RUN_SEEDS into ``out`` with the session's compiled ``program``."""
    from advisor_jax.training.host_loop import run_training

    kw = {"eval_episodes": 0, "checkpoint_every": 0, "progress": False, **kw}
    return run_training(TINY, RUN_HP, {}, RUN_SEEDS, out, program=program, **kw)


@pytest.fixture(scope="session")
def straight_run(tmp_path_factory, tiny_functions):
    """The TINY population trained without interruption (no checkpoints but the final)."""
    out = tmp_path_factory.mktemp("straight")
    train_tiny(out, tiny_functions)
    return out
