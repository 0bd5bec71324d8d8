"""The episodes a brax trainer plays, counted on the host: the paper's episode budget.

brax's trainers count environment steps; the paper's budget is N_total episodes (500 in
simulation). ``RecordingWrapper`` sits outermost on the training env (around
``envs.brax_env.wrap_for_training``) and, on every step where some env ended an episode,
sends the ended episodes' outcome, length, return and collision speed to the host
(``jax.debug.callback``, inside a ``lax.cond`` so that other steps pay nothing), each tagged
with the index of the vectorised step (``info["vector_step"]``). ``EpisodeLog`` keeps them in
play order (vectorised step, then env), so after brax has taken S env steps the episodes
completed so far are those of the first S / num_envs vectorised steps.
"""

from __future__ import annotations

import dataclasses
import threading

import jax
import jax.numpy as jnp
import numpy as np
from brax.envs.base import State, Wrapper

from envs import COLLISION, GOAL, TIMEOUT

FIELDS = ("outcome", "length", "episode_return", "collision_speed")


class EpisodeLog:
    """Episodes of one training run as they end (host side, filled by callbacks)."""

    def __init__(self, num_envs: int):
        self.num_envs = num_envs
        self._rows: list[tuple] = []  # (vector step, env, outcome, length, return, speed)
        self._lock = threading.Lock()

    def add(self, step, done, outcome, length, episode_return, collision_speed) -> None:
        """The callback: arrays over the envs of one vectorised step."""
        done = np.asarray(done)
        rows = [
            (int(step), int(e), int(outcome[e]), int(length[e]), float(episode_return[e]),
             float(collision_speed[e]))
            for e in np.flatnonzero(done)
        ]  # fmt: skip
        with self._lock:
            self._rows.extend(rows)

    def played(self, env_steps: int) -> list[tuple]:
        """The episodes completed within the first ``env_steps`` env steps, in play order.
        (``jax.effects_barrier()`` first: callbacks still running would be missed.)"""
        last = env_steps // self.num_envs  # vectorised steps taken
        with self._lock:
            return sorted(r for r in self._rows if r[0] < last)

    def count(self, env_steps: int) -> int:
        return len(self.played(env_steps))

    def arrays(self, env_steps: int, n_total: int) -> dict[str, np.ndarray]:
        """Per-episode arrays [n_total] of the first ``n_total`` episodes completed within
        ``env_steps`` (outcome 0 and NaN where fewer were played), as metrics.npz holds
        them for one agent."""
        rows = self.played(env_steps)[:n_total]
        out = {
            "outcome": np.zeros(n_total, np.int32),
            "length": np.zeros(n_total, np.int32),
            "episode_return": np.full(n_total, np.nan, np.float32),
            "collision_speed": np.full(n_total, np.nan, np.float32),
        }
        for i, (_, _, outcome, length, ret, speed) in enumerate(rows):
            out["outcome"][i], out["length"][i], out["episode_return"][i] = outcome, length, ret
            if outcome == COLLISION:
                out["collision_speed"][i] = speed
        return out


class RecordingWrapper(Wrapper):
    """Sends every ended episode of a batched, EpisodeWrapper-ed env to ``sink``
    (``EpisodeLog.add``). Outcome: goal or collision from the env's metrics, else timeout."""

    def __init__(self, env, sink):
        super().__init__(env)
        self.sink = sink

    def reset(self, rng: jax.Array) -> State:
        state = self.env.reset(rng)
        # One count per env (brax's VmapWrapper maps all of the state), all equal.
        state.info["vector_step"] = jnp.zeros(rng.shape[:-1], jnp.int32)
        return state

    def step(self, state: State, action: jax.Array) -> State:
        counts = state.info["vector_step"]
        step_index = counts.reshape(-1)[0]
        state = self.env.step(state, action)
        ended = state.info["episode_metrics"]
        done = state.done > 0
        outcome = jnp.where(
            ended["goal"] > 0, GOAL, jnp.where(ended["collision"] > 0, COLLISION, TIMEOUT)
        )
        fields = (
            step_index, done, outcome, ended["length"], ended["sum_reward"],
            ended["collision_speed"],
        )  # fmt: skip

        def send(fields):
            jax.debug.callback(self.sink, *fields)

        jax.lax.cond(jnp.any(done), send, lambda _: None, fields)
        state.info["vector_step"] = counts + 1
        return state


@dataclasses.dataclass
class Budget:
    """The episode budget of one agent: brax trains until ``n_total`` episodes are
    complete (``BudgetReached`` from its progress callback), at most ``ceiling_steps``."""

    n_total: int
    num_envs: int
    h_max: int

    @property
    def ceiling_steps(self) -> int:
        """Env steps within which ``n_total`` episodes surely end: every env's episode lasts
        at most h_max steps, so after (n_total / num_envs + 1) × h_max steps per env each
        has completed at least n_total / num_envs episodes."""
        per_env = -(-self.n_total // self.num_envs) + 1
        return per_env * self.h_max * self.num_envs


class BudgetReached(Exception):
    """Raised from brax's progress callback once the episode budget is used up."""
