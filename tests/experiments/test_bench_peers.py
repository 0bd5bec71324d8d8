"""experiments/bench_peers.py: rejax's TD3 gets our preset's sizes, its rate is the slope of
two run lengths, and a missing peer is one line."""

from __future__ import annotations

import json

import pytest

from advisor_jax.agent.config import preset
from tests.experiments.scripts import load_script

bench_peers = load_script("bench_peers")


def test_a_missing_peer_is_one_line(monkeypatch, capsys):
    def version(name):
        raise bench_peers.metadata.PackageNotFoundError(name)

    monkeypatch.setattr(bench_peers.metadata, "version", version)
    with pytest.raises(SystemExit, match=r'rejax is not installed: pip install -e "\.\[peers\]"'):
        bench_peers.main(["--agents", "1"])


def test_the_rate_is_the_slope_of_two_run_lengths(monkeypatch):
    """E more steps per seed over the extra time: 4 seeds x 1,000 steps / (3.0 - 1.0) s."""
    seconds = {1000: 1.0, 2000: 3.0}
    monkeypatch.setattr(bench_peers, "rejax_td3", lambda preset, agent, steps: steps)
    monkeypatch.setattr(bench_peers, "_best_call", lambda steps, keys, repeats: seconds[steps])
    rate = bench_peers.rejax_rate("quick", "ATD3+AfDP", 4, 1000, repeats=2)
    assert rate["agent_steps_per_s"] == pytest.approx(4 * 1000 / 2.0)
    seconds[2000] = 0.9  # noise larger than the work: refused, not a negative rate
    with pytest.raises(SystemExit, match="raise --steps"):
        bench_peers.rejax_rate("quick", "ATD3+AfDP", 4, 1000, repeats=1)


def test_rejax_gets_our_sizes_batch_and_delay():
    pytest.importorskip("rejax")
    td3 = bench_peers.rejax_td3("paper", "ATD3+AfDP", 2000)
    a = preset("paper", "ATD3+AfDP")[0].agent
    assert td3.actor.hidden_layer_sizes == (600, 300) == tuple(a.actor_hidden)
    assert td3.critic.hidden_layer_sizes == (1000, 500, 600)
    assert (td3.batch_size, td3.buffer_size, td3.policy_delay) == (
        a.batch_size, a.buffer_size, a.policy_delay)  # fmt: skip
    assert (td3.num_envs, td3.num_epochs, td3.total_timesteps, td3.eval_freq) == (1, 1, 2000, 2000)


def test_each_population_is_written_when_measured(monkeypatch, tmp_path):
    """The report holds every population measured before a failure (a run cut short keeps
    its rows), each with rejax's E: 20,000 / seeds, at least 2,000, unless --steps."""
    monkeypatch.setattr(bench_peers.metadata, "version", lambda name: "0")
    monkeypatch.setattr(bench_peers, "full_step", lambda *a: {"agent_steps_per_s": 300.0 * a[2]})

    def rejax_rate(preset, agent, n, steps, repeats):
        if n == 64:
            raise RuntimeError("the machine went away")
        return {"agent_steps_per_s": 100.0 * n, "short_s": 1.0, "long_s": 2.0}

    monkeypatch.setattr(bench_peers, "rejax_rate", rejax_rate)
    argv = ["--agents", "1", "4", "64", "--out", str(tmp_path), "--name", "b"]
    with pytest.raises(RuntimeError):
        bench_peers.main(argv)
    rows = json.loads((tmp_path / "b.json").read_text())["rows"]
    assert [(r["agents"], r["ratio"], r["rejax_steps"]) for r in rows] == [
        (1, 3.0, 20_000), (4, 3.0, 5_000)
    ]  # fmt: skip
    assert "| 4 |" in (tmp_path / "b.md").read_text()
