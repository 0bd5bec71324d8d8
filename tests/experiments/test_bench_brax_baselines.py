"""experiments/bench_brax_baselines.py --brax-cpus: brax seeds as processes on CPU cores, each
type's wall time its own."""

from __future__ import annotations

import argparse
import json
import os
from types import SimpleNamespace

import pytest

from tests.experiments.scripts import load_script

bench = load_script("bench_brax_baselines")


def test_cores_are_a_range_this_machine_has():
    first = min(os.sched_getaffinity(0))
    assert bench.cpu_range(str(first)) == [first]
    with pytest.raises(argparse.ArgumentTypeError, match=r"--brax-cpus 0-4096: .*no core"):
        bench.cpu_range("0-4096")


class FakeProcess:
    """Ends (exit status 0) once the fake clock reaches ``ends_at``."""

    def __init__(self, clock, ends_at):
        self.clock, self.ends_at, self.returncode = clock, ends_at, None

    def poll(self):
        if self.clock["now"] >= self.ends_at:
            self.returncode = 0
        return self.returncode


def test_each_brax_type_is_timed_by_its_own_seeds(monkeypatch, tmp_path):
    """SAC's seeds end at 800 s, PPO's at 90 s: PPO's wall time is 90, not SAC's 800 (read
    in order, it was)."""
    clock = {"now": 0.0}
    monkeypatch.setattr(bench.time, "perf_counter", lambda: clock["now"])
    monkeypatch.setattr(bench.time, "sleep", lambda s: clock.update(now=clock["now"] + s))
    started = []
    for agent, seeds_end in (("brax-SAC", (700, 800)), ("brax-PPO", (80, 90))):
        for seed, end in enumerate(seeds_end):
            out = tmp_path / agent / f"seed{seed:02d}"
            out.mkdir(parents=True)
            run = {
                "train_seconds": end - 10,
                "env_steps_per_agent": [100],
                "episodes_completed": [5],
                "evaluation": {"training": {"success": 0.5}},
            }
            (out / "run.json").write_text(json.dumps(run))
            started.append(bench.BraxSeed(agent, seed, 2, out, FakeProcess(clock, end), 0.0))
    args = SimpleNamespace(preset="quick", eval_episodes=3, episodes=0)
    rows = {r["agent"]: r for r in bench.finish_brax(started, args)}
    assert rows["brax-SAC"]["wall_seconds"] == pytest.approx(800, abs=1)
    assert rows["brax-PPO"]["wall_seconds"] == pytest.approx(90, abs=1)
    assert rows["brax-PPO"]["seconds_per_agent"] == 75.0
    assert "--seed K" in rows["brax-PPO"]["command"]
    assert rows["brax-SAC"]["where"] == "CPU, 2 one-seed processes, 2 core(s) each"
