"""Helpers of the runner tests: an asymmetric actor, synthetic observations, hardware fakes.

The actor has random, asymmetric weights and biases (He kernels plus random offsets) and a
square middle layer, so a transposed or permuted kernel changes the outputs instead of
failing only on a shape. One export per session; tests that tamper copy it first.
"""

from __future__ import annotations

import dataclasses
import math

import jax
import numpy as np

from advisor_jax.agent.networks import init_actor, make_actor
from advisor_jax.deploy.export import export_policy
from advisor_jax.runner.observation import Pose, Scan

HIDDEN = (48, 48)
ENV_META = {
    "arena": "physical",
    "dt": 0.05,
    "v_max": 1.0,
    "omega_max": 2.0,
    "max_range": 1.0,
    "robot_radius": 0.22,
    "lidar_range_offset": 0.22,
    "h_max": 150,
    "T_g": 0.15,
    "T_c": 0.1,
    "bounds": (-2.45, 2.45, -1.5, 1.5),
}
CONFIG_META = {"preset": "physical", "agent": "ATD3+AfDP", "hparams": {"gamma": 0.9}}


def asymmetric_actor_params(hidden=HIDDEN, seed: int = 0):
    """Flax-initialised actor params plus N(0, 0.3²) on every leaf (biases included)."""

    def make(key):
        init_key, noise_key = jax.random.split(key)
        params = init_actor(make_actor(hidden), init_key)
        leaves, tree = jax.tree_util.tree_flatten(params)
        keys = jax.random.split(noise_key, len(leaves))
        noisy = [x + 0.3 * jax.random.normal(k, x.shape) for x, k in zip(leaves, keys, strict=True)]
        return jax.tree_util.tree_unflatten(tree, noisy)

    return jax.jit(make)(jax.random.key(seed))  # one compile instead of one per op


def export_test_actor(params, out, **overrides) -> dict:
    """``export_policy`` with this module's actor size and metadata and 40 rollout-like golden
    rows, each replaceable by a keyword; returns the metadata."""
    kw = dict(
        actor_hidden=HIDDEN,
        env_meta=ENV_META,
        config_meta=CONFIG_META,
        golden_obs=rollout_like_obs(40),
    )
    return export_policy(params, out, **{**kw, **overrides})


def rollout_like_obs(n: int, seed: int = 0) -> np.ndarray:
    """Observations along a plausible drive: smooth zones, δ, d and velocities."""
    rng = np.random.default_rng(seed)
    t = np.arange(n)[:, None] * 0.05
    p = np.clip(0.6 + 0.4 * np.sin(t + np.linspace(0, 2 * math.pi, 16)), 0.0, 1.0)
    delta = ((0.8 * np.sin(0.7 * t) + math.pi) % (2 * math.pi)) - math.pi
    d = np.maximum(3.0 - 0.05 * t, 0.0)
    v = 0.4 * np.concatenate([np.cos(t), np.sin(t)], axis=1)
    obs = np.concatenate([p, delta, d, v], axis=1) + 0.01 * rng.normal(size=(n, 20))
    obs[:, :16] = np.clip(obs[:, :16], 0.0, 1.0)
    return obs.astype(np.float32)


# Fakes of the hardware ------------------------------------------------------------------


class FakeClock:
    """Monotonic clock that only moves when the loop sleeps (or a test advances it)."""

    def __init__(self, t: float = 1000.0):
        self.t = t
        self.sleeps: list[float] = []

    def __call__(self) -> float:
        return self.t

    def sleep(self, seconds: float) -> None:
        self.sleeps.append(seconds)
        self.t += seconds


def ring_scan(distances_m, stamp: float, n: int = 200) -> Scan:
    """An RPLIDAR-format turn with n readings, each zone at the given distance (m)."""
    distances_m = np.broadcast_to(np.asarray(distances_m, np.float64), (16,))
    cw_deg = (np.arange(n) + 0.25) * 360.0 / n  # clockwise, never on a zone boundary
    ccw = (-cw_deg + 180.0) % 360.0 - 180.0
    zone = np.floor((90.0 - ccw) / 22.5).astype(int) % 16
    mm = distances_m[zone] * 1000.0
    return Scan(np.stack([np.full(n, 15.0), cw_deg, mm], axis=1), stamp)


@dataclasses.dataclass
class ScriptedSource:
    """``latest()`` returns ``items[k]`` on its k-th call (the last one after that);
    an Exception item is raised instead; ``make(clock)`` items are built lazily."""

    items: list
    calls: int = 0

    def latest(self):
        item = self.items[min(self.calls, len(self.items) - 1)]
        self.calls += 1
        if isinstance(item, BaseException):
            raise item
        return item() if callable(item) else item

    def close(self):
        pass


class RecordingMotor:
    def __init__(self, fail_on_send: int | None = None):
        self.calls: list = []
        self.fail_on_send = fail_on_send

    def send(self, command):
        if self.fail_on_send is not None and len(self.calls) == self.fail_on_send:
            self.calls.append(("failed", command))
            raise OSError("motor controller unplugged")
        self.calls.append(command)

    def stop(self):
        self.calls.append("stop")

    def close(self):
        self.calls.append("close")


def moving_pose(clock: FakeClock, speed: float = 0.4, theta: float = 0.3):
    """A pose that follows the fake clock: straight line from (-1, -0.5)."""

    def make():
        t = clock.t - 1000.0
        x = -1.0 + speed * math.cos(theta) * t
        y = -0.5 + speed * math.sin(theta) * t
        return Pose(x, y, theta, t, clock.t)

    return make
