"""The car runner's benchmark subject (``bench_runner.py``): the
paper-size actor, exported in a child process so that JAX never enters the timed one,
synthetic lidar scans and tracked poses."""

from __future__ import annotations

import math
import subprocess
import sys
import tempfile

import numpy as np

PAPER_ACTOR_HIDDEN = (600, 300)


def export_paper_actor(out_dir: str) -> None:
    """A freshly initialised paper-size actor (20→600→300→2), exported as the car loads it."""
    import jax

    import envs
    from advisor_jax.agent.networks import init_actor, make_actor
    from advisor_jax.deploy.export import export_policy

    params = init_actor(make_actor(PAPER_ACTOR_HIDDEN), jax.random.key(0))
    rng = np.random.default_rng(1)
    golden = rng.uniform(0.0, 1.0, (64, 20)).astype(np.float32)
    export_policy(
        params,
        out_dir,
        actor_hidden=PAPER_ACTOR_HIDDEN,
        env_meta=envs.make_env("physical").metadata(),  # the arena the car's policy trains in
        config_meta={"preset": "paper", "agent": "ATD3+AfDP"},
        golden_obs=golden,
    )


def load_paper_actor():
    """The paper-size actor, exported in a child process (this module's ``export DIR``: JAX
    never enters this one) and loaded and verified as the car loads it."""
    from advisor_jax.runner.policy import load_policy

    with tempfile.TemporaryDirectory() as tmp:
        subprocess.run(
            [sys.executable, "-m", "advisor_jax.bench.car_subject", "export", tmp], check=True
        )
        policy = load_policy(tmp)
    assert "jax" not in sys.modules
    return policy


def synthetic_scan(rng: np.random.Generator, stamp: float):
    """200 readings over one turn, ~5 % invalid (0 mm), at the resolution the ``rplidar``
    package reports: angle in 1/64 degree (clockwise), distance in 1/4 mm."""
    from advisor_jax.runner.observation import Scan

    angles = np.floor(((np.arange(200) * 1.8 + rng.uniform(0.0, 1.8, 200)) % 360.0) * 64) / 64
    dist = np.floor(rng.uniform(150.0, 6000.0, 200) * 4) / 4
    dist[rng.random(200) < 0.05] = 0.0
    quality = np.full(200, 15.0)
    return Scan(np.stack([quality, angles, dist], axis=1), stamp)


def swinging_poses(n: int) -> list:
    """Tracked poses of a car swinging along x at up to 0.5 m/s, 20 Hz. Made up front: the
    tracker thread builds each Pose when it arrives, outside the control cycle."""
    from advisor_jax.runner.observation import Pose

    return [Pose(math.sin(0.05 * i), 0.1, 0.2, 0.05 * i, 0.0) for i in range(n)]


if __name__ == "__main__":  # the child process of load_paper_actor
    if len(sys.argv) != 3 or sys.argv[1] != "export":
        sys.exit("usage: python -m advisor_jax.bench.car_subject export DIR  (load_paper_actor)")
    export_paper_actor(sys.argv[2])
