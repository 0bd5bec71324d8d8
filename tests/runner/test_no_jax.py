"""The runner works on a machine without JAX: run it with jax/flax/mujoco/optax unimportable."""

from __future__ import annotations

import os
import subprocess
import sys
import textwrap

SCRIPT = textwrap.dedent(
    """
    import importlib.abc, json, math, sys

    BLOCKED = {"jax", "jaxlib", "flax", "mujoco", "optax", "orbax", "mujoco_mjx"}

    class Block(importlib.abc.MetaPathFinder):
        def find_spec(self, name, path=None, target=None):
            if name.split(".")[0] in BLOCKED:
                raise ImportError(f"blocked for this test: {name}")
            return None

    sys.meta_path.insert(0, Block())
    try:
        import jax  # noqa: F401
        raise SystemExit("the import hook does not work")
    except ImportError:
        pass

    import numpy as np
    from advisor_jax.runner import cli, cyclelog, drive, hardware, loop, observation, replay
    from advisor_jax.runner.policy import load_policy

    export_dir, log_path = sys.argv[1], sys.argv[2]
    policy = load_policy(export_dir)  # sha256 + golden-set verification, numpy only

    class Clock:
        t = 50.0
        def __call__(self):
            return self.t
        def sleep(self, s):
            self.t += s

    clock = Clock()
    cw = (np.arange(200) + 0.25) * 1.8

    class Scans:
        def latest(self):
            pts = np.stack([np.full(200, 15.0), cw, 800.0 + 300.0 * np.sin(np.radians(cw))], 1)
            return observation.Scan(pts, clock.t - 0.01)
        def close(self):
            pass

    class Poses:
        def latest(self):
            t = clock.t - 50.0
            return observation.Pose(-1.0 + 0.3 * t, -0.5, 0.0, t, clock.t)
        def close(self):
            pass

    cfg = observation.ObservationConfig(range_offset=0.22, bounds=policy.bounds)
    ctrl = loop.Controller(
        policy, observation.ObservationBuilder(cfg, (1.5, 0.8)),
        drive.DiffDrive(0.4), loop.LoopConfig(max_cycles=8),
    )
    log = cyclelog.JsonlLog(log_path)
    log.write(cyclelog.log_header(ctrl, policy))
    motor = hardware.PrintMotorDriver()
    summary = loop.run_loop(ctrl, Scans(), Poses(), motor, log=log, clock=clock, sleep=clock.sleep)
    assert summary.cycles == 8 and not summary.stops, summary
    assert cli.main(["--replay", log_path]) == 0
    from advisor_jax.cli import car  # advisor-jax-car's entry point: no JAX unless --sim
    assert car.main(["--replay", log_path]) == 0
    assert car.main([export_dir, "--sim"]) == 2  # one line: --sim needs the simulator
    loaded = sorted(m for m in sys.modules if m.split(".")[0] in BLOCKED)
    assert not loaded, loaded
    print("NO-JAX-OK")
    """
)


def test_runner_runs_without_jax(export_dir, tmp_path):
    env = {k: v for k, v in os.environ.items() if k != "PYTHONPATH"}
    proc = subprocess.run(
        [sys.executable, "-c", SCRIPT, str(export_dir), str(tmp_path / "log.jsonl")],
        capture_output=True,
        text=True,
        env=env,
        timeout=120,
    )
    assert proc.returncode == 0, proc.stderr
    assert "NO-JAX-OK" in proc.stdout
    assert proc.stdout.count("[dry-run] diff left=") == 8
    assert "advisor-jax-car: error: --sim needs the simulator" in proc.stderr
