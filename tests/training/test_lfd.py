"""The LfD baseline (docs/baselines.md): phases in the training scan, budget, population,
run directory, CLI and bad input.

One tiny LfD configuration is compiled once (vmapped) and once more for the lone-agent
comparison; the population sweeps D (demo_episodes) over seeds, as a D sweep would.
"""

from __future__ import annotations

import dataclasses
import json

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from advisor_jax.agent.advisor import advisor_action, arena_advisor
from advisor_jax.agent.baselines import BaselineConfig, parse_baseline_settings
from advisor_jax.agent.config import (
    AgentConfig,
    HParams,
    TrainConfig,
    parse_agent,
    preset,
    train_config_from_dict,
)
from advisor_jax.agent.hparams import BaselineHParams, LfdHParams
from advisor_jax.training import checkpoint
from advisor_jax.training.host_loop import run_training
from advisor_jax.training.population import agent_keys, build_population
from advisor_jax.training.program import population_functions
from tests.compare import assert_same_agent
from tests.training.conftest import (
    agent_slice,
    assert_gate_covers_play,
    gate_function,
    primitive_names,
    run_chunks_with_metrics,
)

BC_STEPS, WARMUP = 30, 10
TINY_LFD = TrainConfig(
    agent=parse_agent(
        "LfD",
        actor_hidden=(16, 16),
        critic_state_hidden=32,
        critic_hidden=(32, 32),
        buffer_size=512,
        batch_size=32,
        baseline=BaselineConfig(bc_steps=BC_STEPS, bc_batch=32, critic_warmup=WARMUP),
    ),
    arena="training",
    episodes=4,
    chunk_steps=40,
    max_episode_steps=40,
)
# demo_episodes (slowest) × seeds; OU σ = 0 so that a demonstration's executed action is
# the advisor's own and can be checked exactly.
BASE_HP = BaselineHParams(rl=HParams(lr_actor=1e-3, ou_sigma=0.0), prior=LfdHParams())
GRID = {"demo_episodes": [1.0, 2.0]}
SEEDS = [0, 1]
N_CHUNKS = 5  # max_steps = 4 × 40 + 30 + 10 = 200 = 5 × 40


@pytest.fixture(scope="module")
def lfd_functions():
    return population_functions(TINY_LFD)


def _run(init_fn, chunk_fn, keys, hp, n_chunks=N_CHUNKS, state=None, first=0, gate_fn=None):
    state = init_fn(keys) if state is None else state
    return run_chunks_with_metrics(
        chunk_fn, state, hp, TINY_LFD.chunk_steps, first, n_chunks, gate_fn
    )


@pytest.fixture(scope="module")
def lfd_population(lfd_functions):
    trainer, init_fn, chunk_fn = lfd_functions
    assert trainer.max_steps == N_CHUNKS * TINY_LFD.chunk_steps
    hp, agents = build_population(BASE_HP, GRID, SEEDS)
    keys = agent_keys([a["seed"] for a in agents])
    state, metrics = _run(init_fn, chunk_fn, keys, hp, gate_fn=gate_function(TINY_LFD))
    return state, metrics, hp, agents


def test_imitation_warmup_and_rl_are_real_branches(lfd_population, lfd_functions):
    """The two offline bodies and the RL update are gated ``cond``s, not batched selects:
    once every agent is in RL, a step no longer pays an imitation step and a critic step
    beside its update, and no step pays the RL update while no agent can reach RL in the
    chunk. Outside the batched switch the RL update's own conds (the learner's warm-up
    and the actor's delay, unbatched step index) stay real too: 2 + 1 + 2."""
    _, _, hp, agents = lfd_population
    _, init_fn, chunk_fn = lfd_functions
    state = jax.eval_shape(init_fn, agent_keys([a["seed"] for a in agents]))
    jaxpr = chunk_fn.trace(state, hp, jnp.int32(0)).jaxpr  # cached: no new compile
    assert primitive_names(jaxpr.jaxpr).count("cond") == 5


def test_the_gate_covers_every_phase_played(lfd_population):
    """Every phase an agent played in a chunk had its gate on. Chunk 0: every agent
    demonstrates with 30 + 10 = 40 offline steps before RL, as many as the chunk's 40
    steps, so RL's update is skipped; imitation (0 away) and warm-up (30 away) may start.
    The last chunk: every agent in RL."""
    _, metrics, _, _ = lfd_population
    assert_gate_covers_play(metrics, TINY_LFD.chunk_steps)
    np.testing.assert_array_equal(metrics["gate"][0], [True, True, True, False])
    np.testing.assert_array_equal(metrics["gate"][-1], [False, False, False, True])


def test_gated_run_equals_every_gate_on(lfd_population, lfd_functions):
    """One compiled chunk, two gate inputs: the population's gate, and every gate forced on
    (every gated body and the RL update computed at every step, as without a gate). The
    runs are bit-identical: a gate is only off where no agent uses the body's result."""
    _, metrics, hp, agents = lfd_population
    trainer, init_fn, _ = lfd_functions
    assert not metrics["gate"].all(), "the gated run skipped something"
    chunk = jax.jit(jax.vmap(trainer.chunk, in_axes=(0, 0, None, None)))
    gate_fn = gate_function(TINY_LFD)
    keys = agent_keys([a["seed"] for a in agents])
    runs = []
    for forced in (False, True):

        def chunk_fn(state, hp, first_step, forced=forced):
            gate = gate_fn(state, hp)
            return chunk(state, hp, first_step, jnp.ones_like(gate) if forced else gate)

        runs.append(_run(init_fn, chunk_fn, keys, hp))
    (gated, gated_metrics), (ungated, ungated_metrics) = runs
    for a, b in zip(jax.tree.leaves(gated), jax.tree.leaves(ungated), strict=True):
        np.testing.assert_array_equal(a, b)
    assert gated_metrics.keys() == ungated_metrics.keys()
    for name in gated_metrics:
        np.testing.assert_array_equal(gated_metrics[name], ungated_metrics[name], err_msg=name)


def test_phases_follow_the_schedule(lfd_population, lfd_functions):
    """demo until N = D, then exactly bc_steps imitation and critic_warmup warm-up steps
    (environment held), then RL; each phase computes only its own metrics."""
    state, metrics, hp, _ = lfd_population
    names = lfd_functions[0].phases.names
    assert names == ("demo", "imitate", "warmup", "rl")
    phase, episodes = metrics["train/phase"], metrics["train/episodes"]
    for a in range(phase.shape[0]):
        p = phase[a]
        assert np.all(np.diff(p) >= 0), "phases run in order, once each"
        assert np.sum(p == 1) == BC_STEPS and np.sum(p == 2) == WARMUP
        demo_end = np.flatnonzero(p == 1)[0]  # the first imitation step
        assert episodes[a, demo_end - 1] == hp.prior.demo_episodes[a]  # the D-th demo just ended
        assert np.all(episodes[a, p == 1] == hp.prior.demo_episodes[a])  # no episode while held
        assert np.all(episodes[a, p == 2] == hp.prior.demo_episodes[a])
        assert np.all(np.isfinite(metrics["bc/loss"][a, p == 1]))
        assert np.all(np.isnan(metrics["bc/loss"][a, p != 1]))
        assert np.all(np.isfinite(metrics["critic/warmup_loss"][a, p == 2]))
        assert np.all(np.isnan(metrics["critic/warmup_loss"][a, p != 2]))
        assert np.all(np.isnan(metrics["loss/critic"][a, p < 3]))  # no RL update before RL
        assert np.all(np.isfinite(metrics["loss/actor"][a, p == 3]))
        assert int(state.prior.offline_steps[a]) == BC_STEPS + WARMUP
    assert not state.diverged.any()


def test_demonstrations_are_the_advisors_and_count_in_the_budget(lfd_population):
    """The first D episodes are executed by the advisor (actor firing 0, executed action =
    clean advisor action with σ = 0), the rest by the actor; together exactly N_total, and
    the env steps counted are the episodes' steps (offline phases take none)."""
    state, _, hp, _ = lfd_population
    advisor = arena_advisor_params()
    log = state.log
    for a in range(len(hp.prior.demo_episodes)):
        d = int(hp.prior.demo_episodes[a])
        assert np.all(log.outcome[a] > 0), "all N_total episodes played"
        np.testing.assert_array_equal(log.actor_steps[a, :d], 0)
        np.testing.assert_array_equal(log.actor_steps[a, d:], log.length[a, d:])
        assert int(state.env_steps[a]) == int(log.length[a].sum())
        demo_steps = int(log.length[a, :d].sum())
        data = agent_slice(state.replay.data, a)
        np.testing.assert_allclose(data.action[:demo_steps], data.advisor_action[:demo_steps])
        stored = jax.vmap(advisor_action, in_axes=(0, None))(data.obs[:demo_steps], advisor)
        np.testing.assert_allclose(data.advisor_action[:demo_steps], stored, atol=1e-6)
        # RL steps follow the demonstrations in the buffer and were the actor's.
        rl = slice(demo_steps, int(log.length[a].sum()))
        assert not np.allclose(data.action[rl], data.advisor_action[rl])


def arena_advisor_params():
    import envs

    return arena_advisor(envs.make_env("training", max_episode_steps=40))


def test_vmapped_lfd_population_equals_lone_agents(lfd_population, lfd_functions):
    state, _, hp, agents = lfd_population
    trainer = lfd_functions[0]
    init_fn, chunk_fn = jax.jit(trainer.init), jax.jit(trainer.chunk)
    start = jax.device_get(lfd_functions[1](agent_keys([a["seed"] for a in agents])))
    for i in (0, 3):  # D = 1 and D = 2, different seeds
        hp_i = jax.tree_util.tree_map(lambda x, i=i: x[i], hp)
        key = agent_keys([agents[i]["seed"]])[0]
        alone = init_fn(key)
        for c in range(N_CHUNKS):
            alone, _ = chunk_fn(alone, hp_i, jnp.int32(c * TINY_LFD.chunk_steps))
        alone = jax.device_get(alone)
        got = agent_slice(state, i)
        assert_same_agent(got, alone, agent_slice(start, i), i)
        np.testing.assert_array_equal(got.prior.offline_steps, alone.prior.offline_steps)


def test_checkpoint_resume_inside_a_phase_equals_uninterrupted(
    lfd_population, lfd_functions, tmp_path
):
    """Stop after 2 chunks (agents 0, 1 in the critic warm-up, 2, 3 still demonstrating),
    checkpoint, restore, finish: identical to the straight run."""
    state_ref, _, hp, agents = lfd_population
    _, init_fn, chunk_fn = lfd_functions
    keys = agent_keys([a["seed"] for a in agents])
    state, metrics = _run(init_fn, chunk_fn, keys, hp, n_chunks=2)
    assert np.any(metrics["train/phase"][:, -1] == 2), "a stop inside an offline phase"
    checkpoint.save_step(tmp_path, 2 * TINY_LFD.chunk_steps, state)
    restored, _ = checkpoint.restore_latest(tmp_path, jax.eval_shape(init_fn, keys))
    final, _ = _run(init_fn, chunk_fn, keys, hp, state=restored, first=2)
    for a, b in zip(jax.tree.leaves(final), jax.tree.leaves(state_ref), strict=True):
        np.testing.assert_array_equal(np.asarray(a), np.asarray(b))


def test_lfd_run_directory(lfd_functions, tmp_path):
    """run_training writes an LfD run: name, phases, per-episode phase column, and its
    config reads back (resume and export use train_config_from_dict)."""
    out = tmp_path / "lfd"
    summary = run_training(
        TINY_LFD, BASE_HP, GRID, SEEDS, out, eval_episodes=0, checkpoint_every=0,
        progress=False, program=lfd_functions,
    )  # fmt: skip
    saved = json.loads((out / "run.json").read_text())
    assert saved["agent"] == "LfD" and summary["status"] == "finished"
    assert [p["name"] for p in saved["phases"]] == ["demo", "imitate", "warmup", "rl"]
    assert train_config_from_dict(saved["config"]) == TINY_LFD
    rows = [line.split(",") for line in (out / "episodes.csv").read_text().splitlines()]
    assert rows[0][-1] == "phase"
    for i, agent in enumerate(saved["agents"]):
        phases = [r[-1] for r in rows[1:] if r[0] == str(i)]
        d = int(agent["demo_episodes"])
        assert phases == ["demo"] * d + ["rl"] * (TINY_LFD.episodes - d)
    metrics = np.load(out / "metrics.npz")
    assert metrics["phase"].shape == (4, TINY_LFD.episodes)
    with pytest.raises(ValueError, match=r"demo_episodes=4 \(agent 1\) must be below episodes=4"):
        run_training(TINY_LFD, BASE_HP, {"demo_episodes": [1, 4]}, [0], tmp_path / "bad",
                     progress=False, program=lfd_functions)  # fmt: skip
    assert not (tmp_path / "bad").exists(), "checked before anything is written"


# ---- configuration and bad input ------------------------------------------------------


def test_lfd_config_names_round_trip():
    for name in ("paper", "physical", "quick"):
        cfg, hp = preset(name, "LfD")
        assert cfg.agent.name == "LfD" and cfg.agent.algo == "ddpg"
        assert parse_agent(cfg.agent.name) == dataclasses.replace(
            cfg.agent, **{k: getattr(AgentConfig(), k) for k in ("actor_hidden",
            "critic_state_hidden", "critic_hidden", "buffer_size", "batch_size",
            "policy_delay")}, baseline=BaselineConfig())  # fmt: skip
        assert train_config_from_dict(dataclasses.asdict(cfg)) == cfg
    assert preset("paper", "LfD")[1].prior.demo_episodes == 250
    assert preset("physical", "LfD")[1].prior.demo_episodes == 100
    td3 = preset("physical", "LfD", baseline={"learner": "td3"})[0].agent
    assert td3.algo == "td3" and td3.twin and td3.delay == 3 and td3.name == "LfD"
    assert preset("quick", "lfd")[0].agent.baseline.bc_steps == 200


@pytest.mark.parametrize(
    "make, message",
    [
        (lambda: parse_agent("LfD+AfD"), "takes no advisor switches"),
        (lambda: preset("paper", "LfD", baseline={"learner": "addpg"}), "learner='addpg'"),
        (lambda: parse_baseline_settings(["mpc_horizn=10"], "lfd", "LfD"),
         "unknown baseline setting 'mpc_horizn'.*bc_steps"),
        (lambda: parse_baseline_settings(["bc_steps=1.5"], "lfd", "LfD"), "bc_steps='1.5'"),
        (lambda: parse_baseline_settings(["bc_steps=5"], None, "DDPG"),
         "unknown baseline setting 'bc_steps': agent 'DDPG' is not a baseline"),
        (lambda: preset("paper", "DDPG", baseline={"bc_steps": 5}), "not a baseline"),
        (lambda: BaselineConfig(bc_steps=0), "bc_steps must be a positive integer, got 0"),
        (lambda: BaselineConfig(bc_steps=-3), "bc_steps must be a positive integer, got -3"),
        (lambda: BaselineConfig(bc_batch=0), "bc_batch must be a positive integer, got 0"),
        (lambda: BaselineConfig(critic_warmup=-1), "critic_warmup must be an integer >= 0"),
        (lambda: BaselineConfig(kind="mbmf"), "unknown baseline kind 'mbmf'"),
        (lambda: dataclasses.replace(TINY_LFD, envs_per_agent=4), "envs_per_agent=4"),
    ],
)  # fmt: skip
def test_bad_baseline_configuration_is_named(make, message):
    with pytest.raises(ValueError, match=message):
        make()


def test_cli_builds_an_lfd_population():
    """``advisor-jax train --agent LfD`` on the quick preset with a D sweep and TD3: the
    config and hyperparameters the run gets (training itself: test_lfd_run_directory)."""
    from advisor_jax.cli.train import TrainArgs, build_run

    args = TrainArgs(agent="LfD", preset="quick", seeds=2, grid=("demo_episodes=10,30",),
                     hp=("bc_lr=3e-4",), baseline=("learner=td3", "critic_warmup=0"))  # fmt: skip
    cfg, base_hp, grid, seeds, _ = build_run(args)
    assert cfg.agent.name == "LfD" and cfg.agent.algo == "td3"
    assert cfg.agent.baseline == BaselineConfig(bc_steps=200, bc_batch=128, critic_warmup=0)
    assert grid == {"demo_episodes": [10.0, 30.0]} and seeds == [0, 1]
    assert base_hp.prior.bc_lr == pytest.approx(3e-4) and cfg.episodes == 60


@pytest.mark.parametrize(
    "argv, needle",
    [
        (["--agent", "LfD", "--hp", "demo_episodes=60"],
         "demo_episodes=60 must be below episodes=60 (N_total)"),
        (["--agent", "LfD", "--grid", "demo_episodes=10,600"],
         "demo_episodes=600 (agent 1) must be below episodes=60"),
        (["--agent", "LfD", "--hp", "demo_episodes=2.5"], "demo_episodes=2.5 must be a whole"),
        (["--agent", "LfD", "--baseline", "bc_steps=0"], "bc_steps must be a positive integer"),
        (["--agent", "LfD", "--baseline", "learner=addpg"], "learner='addpg'"),
        (["--agent", "LfD", "--baseline", "model_hidden=5"], "unknown baseline setting"),
        (["--agent", "DDPG", "--hp", "demo_episodes=5"], "unknown baseline setting demo_ep"),
        (["--agent", "LfD", "--envs-per-agent", "4"], "envs_per_agent=4"),
    ],
)  # fmt: skip
def test_cli_bad_baseline_input_is_one_line(argv, needle, tmp_path, capsys):
    from advisor_jax.cli.main import main

    with pytest.raises(SystemExit) as exit_info:
        main(["train", "--out", str(tmp_path / "run"), "--no-progress", *argv])
    err = capsys.readouterr().err
    assert exit_info.value.code == 2 and "Traceback" not in err
    assert needle in " ".join(err.split()), err
    assert not (tmp_path / "run").exists()


def test_demonstrations_come_from_the_runs_advisor():
    """LfD consults the advisor through the interface: with a registered advisor that always
    proposes (0.3, -0.2), every demonstration step executes it (OU σ = 0) and stores it as
    a_adv; once RL starts the actor acts."""
    from advisor_jax.agent.advisors import register_advisor

    register_advisor("test_lfd_constant", lambda p, obs: p + 0.0 * obs[:2], jnp.array([0.3, -0.2]))
    cfg = dataclasses.replace(TINY_LFD, episodes=2, advisor="test_lfd_constant")
    trainer, init_fn, chunk_fn = population_functions(cfg)
    hp, agents = build_population(BASE_HP, {"demo_episodes": [1.0]}, [0])
    state, _ = _run(init_fn, chunk_fn, agent_keys([0]), hp, n_chunks=3)
    data, length = agent_slice(state.replay.data, 0), np.asarray(state.log.length[0])
    demo = slice(0, int(length[0]))
    np.testing.assert_allclose(data.action[demo], np.tile([0.3, -0.2], (length[0], 1)), atol=1e-7)
    np.testing.assert_allclose(data.advisor_action[demo], data.action[demo])
    assert trainer.advisor.kind == "registered"
    rl = slice(int(length[0]), int(length.sum()))
    assert not np.allclose(data.action[rl], [0.3, -0.2])
