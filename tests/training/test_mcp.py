"""The MCP+MF baseline (docs/baselines.md): phases in the training scan, the budget, the
model fit, population = alone, resume, run directory, presets and bad input.

One tiny MCP+MF configuration is compiled once (vmapped, ~1 min on 2 cores) and reused by
every test that trains: "alone" runs each agent as a population of copies of itself
(same program, so the gate comes from that agent only), and the run directory goes through
``run_training(program=...)``. The population sweeps M (mpc_episodes) over seeds.
"""

from __future__ import annotations

import dataclasses
import json

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from advisor_jax.agent.baselines import BaselineConfig, parse_baseline_settings
from advisor_jax.agent.config import (
    HParams,
    TrainConfig,
    parse_agent,
    preset,
    train_config_from_dict,
)
from advisor_jax.agent.hparams import BaselineHParams, McpHParams
from advisor_jax.training import checkpoint
from advisor_jax.training.host_loop import run_training
from advisor_jax.training.population import agent_keys, build_population
from advisor_jax.training.prior import phases
from advisor_jax.training.prior.trainer import make_prior_program
from advisor_jax.training.program import population_functions
from advisor_jax.training.run_directory import load_actor
from tests.compare import assert_same_agent
from tests.training.conftest import (
    agent_slice,
    assert_gate_covers_play,
    gate_function,
    primitive_names,
    run_chunks_with_metrics,
)

MODEL_STEPS, BC_STEPS, WARMUP, MPC_ROUNDS, DAGGER_ROUNDS = 30, 20, 10, 2, 1
TINY_MCP = TrainConfig(
    agent=parse_agent(
        "MCP+MF",
        actor_hidden=(16, 16),
        critic_state_hidden=32,
        critic_hidden=(32, 32),
        buffer_size=1024,
        batch_size=32,
        baseline=BaselineConfig(
            kind="mcp",
            bc_steps=BC_STEPS,
            bc_batch=32,
            critic_warmup=WARMUP,
            model_hidden=(16, 16),
            model_steps=MODEL_STEPS,
            model_batch=32,
            mpc_horizon=3,
            mpc_candidates=8,
            mpc_rounds=MPC_ROUNDS,
            dagger_rounds=DAGGER_ROUNDS,
        ),  # fmt: skip
    ),
    arena="training",
    episodes=8,
    chunk_steps=40,
    max_episode_steps=30,
)
# R = 1, M ∈ {1, 2} (slowest) × seeds, one DAgger episode per round: 1 + 2M + 1 < 8.
# OU σ = 0: a DAgger step executes the actor's own action.
BASE_HP = BaselineHParams(
    rl=HParams(lr_actor=1e-3, ou_sigma=0.0),
    prior=McpHParams(random_episodes=1, dagger_episodes=1),
)
GRID = {"mpc_episodes": [1.0, 2.0]}
SEEDS = [0, 1]
OFFLINE = 1 + MODEL_STEPS * (1 + MPC_ROUNDS) + BC_STEPS * (1 + DAGGER_ROUNDS) + WARMUP
N_CHUNKS = -(-(8 * 30 + OFFLINE) // 40)  # max_steps = 8 × 30 + 141 = 381 → 10 chunks
NAMES = ("random", "normalise", "fit_model", "mpc", "fit_model", "mpc", "fit_model",
         "fit_actor", "dagger", "fit_actor", "warmup", "rl")  # fmt: skip


@pytest.fixture(scope="module")
def mcp_functions():
    return population_functions(TINY_MCP)


def _run(chunk_fn, state, hp, first=0, last=N_CHUNKS, gate_fn=None):
    return run_chunks_with_metrics(chunk_fn, state, hp, TINY_MCP.chunk_steps, first, last, gate_fn)


@pytest.fixture(scope="module")
def mcp_population(mcp_functions):
    trainer, init_fn, chunk_fn = mcp_functions
    assert trainer.max_steps == 8 * 30 + OFFLINE
    hp, agents = build_population(BASE_HP, GRID, SEEDS)
    keys = agent_keys([a["seed"] for a in agents])
    start = jax.device_get(init_fn(keys))  # the chunk donates its input
    state, metrics = _run(chunk_fn, init_fn(keys), hp, gate_fn=gate_function(TINY_MCP))
    return state, metrics, hp, agents, start


def _episode_phase(hp, a):
    """Per episode of agent ``a``: its collect phase name (random, mpc, dagger, rl)."""
    r, m, d = (int(getattr(hp.prior, f)[a]) for f in ("random_episodes", "mpc_episodes",
                                                 "dagger_episodes"))  # fmt: skip
    names = ["random"] * r + ["mpc"] * (MPC_ROUNDS * m) + ["dagger"] * (DAGGER_ROUNDS * d)
    return names + ["rl"] * (TINY_MCP.episodes - len(names))


def test_phases_follow_the_schedule(mcp_population, mcp_functions):
    """Phases in order; each offline phase takes exactly its steps with the env held;
    each collect phase ends at its episode count; each computes only its own metrics."""
    state, metrics, hp, _, _ = mcp_population
    assert mcp_functions[0].phases.names == NAMES
    phase, episodes = metrics["train/phase"], metrics["train/episodes"]
    for a in range(phase.shape[0]):
        p = phase[a]
        assert np.all(np.diff(p) >= 0), "phases run in order, once each"
        assert [int(np.sum(p == i)) for i in (1, 2, 4, 6, 7, 9, 10)] == [
            1, MODEL_STEPS, MODEL_STEPS, MODEL_STEPS, BC_STEPS, BC_STEPS, WARMUP]  # fmt: skip
        m = int(hp.prior.mpc_episodes[a])
        targets = {0: 1, 3: 1 + m, 5: 1 + 2 * m, 8: 2 + 2 * m}  # collect phase -> N at its end
        for i, n in targets.items():
            after = np.flatnonzero(p == i + 1)
            assert episodes[a, after[0] - 1] == n and np.all(episodes[a, after] == n)
        model_loss, bc_loss = metrics["model/loss"][a], metrics["bc/loss"][a]
        fits = np.isin(p, (2, 4, 6))
        assert np.all(np.isfinite(model_loss[fits])) and np.all(np.isnan(model_loss[~fits]))
        imitate = np.isin(p, (7, 9))
        assert np.all(np.isfinite(bc_loss[imitate])) and np.all(np.isnan(bc_loss[~imitate]))
        assert np.all(np.isnan(metrics["loss/critic"][a, p < 11]))  # no RL update before RL
        assert np.all(np.isfinite(metrics["loss/actor"][a, p == 11]))
        assert int(state.prior.offline_steps[a]) == OFFLINE
    assert not state.diverged.any()


def test_episodes_by_their_controllers_count_in_the_budget(mcp_population):
    """All N_total episodes played, every one counted: random and MPC episodes without the
    actor, DAgger and RL episodes by the actor; the env steps counted are the episodes'
    steps (offline phases take none). Random rows: uniform actions (not the stored label);
    MPC rows: the executed action is the stored MPC label; DAgger rows: the actor's action
    executed, the MPC's stored as the label; labelled rows start after the random data."""
    state, _, hp, _, _ = mcp_population
    log = state.log
    for a in range(len(hp.prior.mpc_episodes)):
        names = np.array(_episode_phase(hp, a))
        assert np.all(log.outcome[a] > 0), "all N_total episodes played"
        by_actor = np.isin(names, ("dagger", "rl"))
        np.testing.assert_array_equal(log.actor_steps[a, ~by_actor], 0)
        np.testing.assert_array_equal(log.actor_steps[a, by_actor], log.length[a, by_actor])
        assert int(state.env_steps[a]) == int(log.length[a].sum())
        ends = np.cumsum(log.length[a])
        rows = {name: np.concatenate([np.arange(e - n, e) for e, n, k in
                zip(ends, log.length[a], names, strict=True) if k == name])
                for name in ("random", "mpc", "dagger")}  # fmt: skip
        data = agent_slice(state.replay.data, a)
        random, mpc, dagger = (rows[k] for k in ("random", "mpc", "dagger"))
        assert int(state.prior.data.label_start[a]) == len(random) == random[-1] + 1
        assert np.std(data.action[random, 0]) > 0.15 and np.std(data.action[random, 1]) > 0.3
        assert not np.any(np.all(data.action[random] == data.advisor_action[random], -1))
        np.testing.assert_array_equal(data.action[mpc], data.advisor_action[mpc])
        assert np.all((data.action[mpc] >= [0, -1]) & (data.action[mpc] <= [1, 1]))
        assert not np.allclose(data.action[dagger], data.advisor_action[dagger])


def test_the_model_is_fitted(mcp_population):
    """The first fit (random data only, normaliser just set): the loss falls, and the
    model's parameters and normaliser have left their initial values."""
    state, metrics, hp, _, start = mcp_population
    for a in range(len(hp.prior.mpc_episodes)):
        first_fit = metrics["model/loss"][a, metrics["train/phase"][a] == 2]
        assert np.mean(first_fit[-5:]) < 0.8 * np.mean(first_fit[:5]), first_fit
        model, model0 = agent_slice(state.prior.data.model, a), agent_slice(
            start.prior.data.model, a)  # fmt: skip
        assert not np.allclose(model.norm.obs_std, 1.0) and np.all(model.norm.delta_std > 0)
        for x, x0 in zip(jax.tree.leaves(model.params), jax.tree.leaves(model0.params),
                         strict=True):  # fmt: skip
            assert not np.allclose(x, x0)


def test_population_equals_agents_alone(mcp_population, mcp_functions):
    """Agent i in the population (gate from all four) = agent i in a population of copies
    of itself (gate from it alone): neither its neighbours nor the gate change it."""
    state, _, hp, agents, start = mcp_population
    _, init_fn, chunk_fn = mcp_functions
    for i in (0, 3):  # M = 1 and M = 2, different seeds
        hp_i = jax.tree_util.tree_map(lambda x, i=i: np.repeat(x[i : i + 1], 4), hp)
        alone, _ = _run(chunk_fn, init_fn(agent_keys([agents[i]["seed"]] * 4)), hp_i)
        got, want = agent_slice(state, i), agent_slice(alone, 0)
        assert_same_agent(got, want, agent_slice(start, i), i)
        np.testing.assert_array_equal(got.prior.offline_steps, want.prior.offline_steps)
        for x, y in zip(jax.tree.leaves(got.prior.data.model.params),
                        jax.tree.leaves(want.prior.data.model.params), strict=True):  # fmt: skip
            np.testing.assert_allclose(x, y, rtol=1e-4, atol=1e-6)


def test_resume_inside_a_phase_equals_uninterrupted(mcp_population, mcp_functions, tmp_path):
    """Stop after 3 chunks (inside the MPC rounds and model fits), checkpoint, restore,
    finish: identical to the straight run (the model is in the checkpointed state)."""
    state_ref, _, hp, agents, _ = mcp_population
    _, init_fn, chunk_fn = mcp_functions
    keys = agent_keys([a["seed"] for a in agents])
    state, metrics = _run(chunk_fn, init_fn(keys), hp, last=3)
    assert np.any(np.isin(metrics["train/phase"][:, -1], (3, 4, 5, 6))), metrics["train/phase"]
    checkpoint.save_step(tmp_path, 3 * TINY_MCP.chunk_steps, state)
    restored, _ = checkpoint.restore_latest(tmp_path, jax.eval_shape(init_fn, keys))
    final, _ = _run(chunk_fn, restored, hp, first=3)
    for a, b in zip(jax.tree.leaves(final), jax.tree.leaves(state_ref), strict=True):
        np.testing.assert_array_equal(np.asarray(a), np.asarray(b))


def test_mcp_run_directory(mcp_functions, tmp_path):
    """run_training writes an MCP+MF run: name, phases, per-episode phase column, the model
    in params/; its config reads back; a budget overrun is refused before anything is
    written."""
    out = tmp_path / "mcp"
    summary = run_training(
        TINY_MCP, BASE_HP, GRID, SEEDS, out, eval_episodes=0, checkpoint_every=0,
        progress=False, program=mcp_functions,
    )  # fmt: skip
    saved = json.loads((out / "run.json").read_text())
    assert saved["agent"] == "MCP+MF" and summary["status"] == "finished"
    assert tuple(p["name"] for p in saved["phases"]) == NAMES
    assert train_config_from_dict(saved["config"]) == TINY_MCP
    hp, _ = build_population(BASE_HP, GRID, SEEDS)
    rows = [line.split(",") for line in (out / "episodes.csv").read_text().splitlines()]
    for i in range(len(saved["agents"])):
        assert [r[-1] for r in rows[1:] if r[0] == str(i)] == _episode_phase(hp, i)
    assert "model_norm" in (out / "params" / "_METADATA").read_text()  # the model is saved
    cfg, row, actor = load_actor(out, 1)  # what export reads: the actor alone
    assert cfg == TINY_MCP and row["mpc_episodes"] == 1.0
    assert actor["params"]["hidden_0"]["kernel"].shape == (20, 16)
    with pytest.raises(ValueError, match=r"= 8 \(agent 1\) must be below episodes=8"):
        run_training(TINY_MCP, BASE_HP, {"mpc_episodes": [1, 3]}, [0], tmp_path / "bad",
                     progress=False, program=mcp_functions)  # fmt: skip
    assert not (tmp_path / "bad").exists(), "checked before anything is written"


def test_heavy_bodies_are_real_branches(mcp_population, mcp_functions):
    """In the population's program the MPC plan, the four gated offline bodies
    (normalise, fit_model, fit_actor, warmup) and the RL update are ``cond``s, not batched
    selects: each is skipped while the population's gate is off (no agent can be in a
    phase that uses it during the chunk). Outside the batched switch the RL update's own
    conds (the learner's warm-up, the actor's delay) stay real too: 5 + 1 + 2."""
    _, _, hp, agents, _ = mcp_population
    _, init_fn, chunk_fn = mcp_functions
    state = jax.eval_shape(init_fn, agent_keys([a["seed"] for a in agents]))
    jaxpr = chunk_fn.trace(state, hp, jnp.int32(0)).jaxpr  # cached: no new compile
    assert primitive_names(jaxpr.jaxpr).count("cond") == 8


def test_the_gate_covers_every_phase_played(mcp_population, mcp_functions):
    """Every phase an agent played in a chunk had its gate on (the MPC plan: on whenever an
    mpc or dagger phase was). Chunk 0: every agent in the random phase, so k = 0 and only
    the phases fewer than 40 offline steps away may run: up to the first mpc round's fit
    (normalise 1 + fit_model 30 steps before it); the second round, the actor fits,
    DAgger, warm-up and RL are off."""
    _, metrics, _, _, _ = mcp_population
    assert_gate_covers_play(metrics, TINY_MCP.chunk_steps)
    schedule = make_prior_program(TINY_MCP).schedule
    before = phases.offline_before(schedule)
    np.testing.assert_array_equal(before[:6], [0, 0, 1, 31, 31, 61])
    np.testing.assert_array_equal(metrics["gate"][0], before < TINY_MCP.chunk_steps)
    np.testing.assert_array_equal(metrics["gate"][-1], [False] * 11 + [True])


# ---- configuration and bad input ------------------------------------------------------


def test_mcp_presets_and_config_round_trip():
    for name, counts in (("paper", (50, 40, 10)), ("physical", (20, 16, 4)),
                         ("quick", (6, 8, 4))):  # fmt: skip
        cfg, hp = preset(name, "MCP+MF")
        assert cfg.agent.name == "MCP+MF" and cfg.agent.algo == "ddpg"
        assert (hp.prior.random_episodes, hp.prior.mpc_episodes, hp.prior.dagger_episodes) == (
            counts
        )
        assert train_config_from_dict(json.loads(json.dumps(dataclasses.asdict(cfg)))) == cfg
        b = cfg.agent.baseline
        assert 2 * (counts[0] + b.mpc_rounds * counts[1] + b.dagger_rounds * counts[2]) == (
            cfg.episodes)  # the shared 50 % rule  # fmt: skip
    paper = preset("paper", "mcp+mf")[0].agent.baseline
    assert (paper.model_hidden, paper.mpc_candidates, paper.mpc_horizon) == ((500, 500), 1000, 20)
    quick = preset("quick", "MCP+MF", baseline={"learner": "td3", "model_hidden": (32,)})[0]
    assert quick.agent.algo == "td3" and quick.agent.baseline.model_hidden == (32,)
    assert quick.agent.baseline.mpc_candidates == 64 and quick.agent.baseline.mpc_rounds == 2
    assert preset("quick", "LfD")[0].agent.baseline == BaselineConfig(
        bc_steps=200, bc_batch=128, critic_warmup=100
    )  # LfD takes only its own keys


@pytest.mark.parametrize(
    "make, message",
    [
        (lambda: BaselineConfig(kind="mcp", mpc_horizon=0),
         "mpc_horizon must be a positive integer, got 0"),
        (lambda: BaselineConfig(kind="mcp", mpc_candidates=0),
         "mpc_candidates must be a positive integer, got 0"),
        (lambda: BaselineConfig(kind="mcp", mpc_candidates=-5), "got -5"),
        (lambda: BaselineConfig(kind="mcp", model_hidden=(64, 0)), "model_hidden.*64,0"),
        (lambda: BaselineConfig(kind="mcp", dagger_rounds=-1), "dagger_rounds must be"),
        (lambda: parse_baseline_settings(["mpc_horizn=10"], "mcp", "MCP+MF"),
         "unknown baseline setting 'mpc_horizn' for MCP\\+MF.*mpc_horizon"),
        (lambda: parse_baseline_settings(["model_hidden=64,x"], "mcp", "MCP+MF"),
         "model_hidden='64,x'"),
        (lambda: parse_baseline_settings(["mpc_rounds=2"], "lfd", "LfD"),
         "unknown baseline setting 'mpc_rounds' for LfD"),
        (lambda: parse_agent("MCP+MF+AfD"), "unknown agent"),
        (lambda: dataclasses.replace(TINY_MCP, envs_per_agent=2), "envs_per_agent=2"),
    ],
)  # fmt: skip
def test_bad_mcp_configuration_is_named(make, message):
    with pytest.raises(ValueError, match=message):
        make()


@pytest.mark.parametrize(
    "argv, needle",
    [
        (["--hp", "random_episodes=16"],
         "16 + 2·8 + 2·4 = 40 must be below episodes=40 (N_total)"),
        (["--grid", "mpc_episodes=8,20"], "6 + 2·20 + 2·4 = 54 (agent 1) must be below"),
        (["--hp", "mpc_episodes=0"], "mpc_episodes=0 must be a whole number >= 1"),
        (["--hp", "dagger_episodes=1.5"], "dagger_episodes=1.5 must be a whole number"),
        (["--baseline", "mpc_horizon=0"], "mpc_horizon must be a positive integer, got 0"),
        (["--baseline", "mpc_candidates=0"], "mpc_candidates must be a positive integer, got 0"),
        (["--baseline", "mpc_horizn=5"], "unknown baseline setting 'mpc_horizn'"),
        (["--hp", "demo_episodes=5"], "unknown baseline setting demo_episodes: agent 'MCP+MF'"),
    ],
)  # fmt: skip
def test_cli_bad_mcp_input_is_one_line(argv, needle, tmp_path, capsys):
    from advisor_jax.cli.main import main

    with pytest.raises(SystemExit) as exit_info:
        main(["train", "--agent", "MCP+MF", "--episodes", "40", "--out",
              str(tmp_path / "run"), "--no-progress", *argv])  # fmt: skip
    err = capsys.readouterr().err
    assert exit_info.value.code == 2 and "Traceback" not in err
    assert needle in " ".join(err.split()), err
    assert not (tmp_path / "run").exists()
