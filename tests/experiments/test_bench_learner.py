"""``advisor_jax.bench.learner_loop`` times the update step training runs: the steady and
latency-bound programs' blocks of d updates (the first with the actor step), with no
conditional, or the general program's ``lax.cond`` per update. The loops must compute the same
updates."""

from __future__ import annotations

import jax
import numpy as np
import pytest

from advisor_jax.agent.config import parse_agent
from advisor_jax.bench import learner_loop

TINY_LEARNER = parse_agent(
    "ATD3+AfDP", actor_hidden=(16, 16), critic_state_hidden=32, critic_hidden=(32, 32),
    buffer_size=256, batch_size=32, policy_delay=2,
)  # fmt: skip


def _run(program: str, n_updates: int, n_agents: int = 2):
    learner, loop = learner_loop.make_update_loop(TINY_LEARNER, n_updates, program, n_agents)
    keys = jax.random.split(jax.random.PRNGKey(0), n_agents)
    states = jax.jit(jax.vmap(learner.init))(keys)
    replays = jax.vmap(learner_loop.fill_replay, in_axes=(None, 0))(256, keys)
    return jax.device_get(loop(states, replays, keys))


@pytest.mark.parametrize("program", ["steady", "latency-bound"])
def test_the_block_loops_compute_the_conditional_loops_updates(program):
    general, blocks = _run("general", 6), _run(program, 6)
    assert general.actor_updates.tolist() == blocks.actor_updates.tolist() == [3, 3]
    assert general.critic_updates.tolist() == [6, 6]
    for x, y in zip(jax.tree.leaves(general), jax.tree.leaves(blocks), strict=True):
        np.testing.assert_allclose(x, y, rtol=1e-4, atol=1e-6)


def test_a_block_loop_of_part_of_a_block_is_refused():
    assert _run("general", 5, n_agents=1).actor_updates.tolist() == [3]
    for program in ("steady", "latency-bound"):
        with pytest.raises(ValueError, match="5 updates.*d = 2"):
            learner_loop.make_update_loop(TINY_LEARNER, 5, program)
    with pytest.raises(ValueError, match="stedy"):
        learner_loop.make_update_loop(TINY_LEARNER, 6, "stedy")


def test_the_loop_takes_the_layout_training_gives_its_program(monkeypatch):
    """``make_update_loop`` asks ``program_layout`` with the program and agents per device."""
    asked = []
    real = learner_loop.program_layout

    def spy(name, precision, backend=None, agents_per_device=None):
        asked.append((name, precision, agents_per_device))
        return real(name, precision, backend, agents_per_device)

    monkeypatch.setattr(learner_loop, "program_layout", spy)
    learner_loop.make_update_loop(TINY_LEARNER, 6, "steady", agents_per_device=128)
    learner_loop.make_update_loop(TINY_LEARNER, 5, "general", agents_per_device=64)
    assert asked == [("steady", "fp32", 128), ("general", "fp32", 64)]


def test_the_report_records_its_command(tmp_path, monkeypatch):
    # Each row of results/bench_learner.json names the command that measured it.
    import json
    import sys

    from tests.experiments.scripts import load_script

    argv = ["--small", "--agents", "1", "--updates", "2", "--precision", "fp32", "--out"]
    monkeypatch.setattr(sys, "argv", ["bench_learner.py", *argv, str(tmp_path)])
    load_script("bench_learner").main()
    command = json.loads((tmp_path / "bench_learner.json").read_text())["command"]
    assert command == f"python experiments/bench_learner.py {' '.join(argv)} {tmp_path}"
    assert f"Command: `{command}`" in (tmp_path / "bench_learner.md").read_text()


def test_the_reference_times_the_same_program(tmp_path):
    """``--reference`` passes ``--program`` to a tree that knows it; an older tree would time
    the general loop, so asking it for another program is refused."""
    from tests.experiments.scripts import load_script

    argv_for = load_script("bench_learner").reference_program_argv
    script = tmp_path / "experiments" / "bench_learner.py"
    script.parent.mkdir()
    script.write_text('parser.add_argument("--program")\n')
    assert argv_for(tmp_path, "steady") == ["--program", "steady"]
    script.write_text('parser.add_argument("--agents")\n')
    assert argv_for(tmp_path, "general") == []
    with pytest.raises(SystemExit, match="no --program"):
        argv_for(tmp_path, "steady")


def test_a_block_program_refuses_an_update_count_it_would_not_time(monkeypatch, capsys):
    """``--program steady`` with updates that are not whole blocks of d would time the
    general loop: the scripts refuse it, naming the count and d, before measuring anything."""
    import sys

    from tests.experiments.scripts import load_script

    assert learner_loop.require_whole_blocks(TINY_LEARNER, 6, "steady") == "steady"
    with pytest.raises(ValueError, match="5 updates.*d = 2"):
        learner_loop.require_whole_blocks(TINY_LEARNER, 5, "steady")
    for script in ("bench_learner", "profile_learner"):
        argv = [f"{script}.py", "--small", "--agents", "1", "--updates", "5", "--program", "steady"]
        monkeypatch.setattr(sys, "argv", argv)
        with pytest.raises(SystemExit) as exit_:
            load_script(script).main()
        assert exit_.value.code == 2
        assert "d = 4" in capsys.readouterr().err


def test_the_ceilings_sentence_names_fp32_precision_only_where_fp32_was_measured():
    from tests.experiments.scripts import load_script

    words = load_script("bench_learner").ceiling_words
    bf16 = words({"bf16": 703.51}, 20, 8192, 2578.54)
    assert bf16 == (
        "Ceilings measured in the same process: bf16 matmul 703.5 TFLOP/s (20 dependent 8192² "
        "products per call, best of 5), device copy 2579 GB/s."
    )
    both = words({"bf16": 713.8, "fp32": 353.2}, 20, 8192, 2618.0)
    assert "fp32 matmul 353.2 TFLOP/s (fp32 at JAX's default precision; 20 dependent" in both
