"""Shared fixtures of the environment tests.

MJX compiles are the slow part on a CPU, so every jitted function is built once per
session, on demand, through the ``sim`` fixture, and batches are small. Helpers build
hand-placed states (a pose and a goal chosen by the test) whose observation comes from the
same MJX sensor pass the environment uses.
"""

from __future__ import annotations

import contextlib
import io
from collections.abc import Callable
from typing import Any

import jax
import jax.numpy as jnp
import mujoco
import numpy as np
import pytest

with contextlib.redirect_stdout(io.StringIO()):  # MJX's "Failed to import warp" notice
    import envs
from envs.navigation import NavEnv, NavState


class Sim:
    """Per-arena environments and their jitted functions, compiled once per session."""

    def __init__(self):
        self._memo: dict[tuple[str, str], Any] = {}

    def _once(self, what: str, arena: str, build: Callable[[], Any]) -> Any:
        if (what, arena) not in self._memo:
            self._memo[what, arena] = build()
        return self._memo[what, arena]

    def env(self, arena: str) -> NavEnv:
        return self._once("env", arena, lambda: envs.make_env(arena))

    def reset(self, arena: str):
        """keys [B, 2] -> NavState [B]."""
        return self._once("reset", arena, lambda: jax.jit(jax.vmap(self.env(arena).reset)))

    def step(self, arena: str):
        """(NavState [B], actions [B, 2]) -> NavState [B]."""
        return self._once("step", arena, lambda: jax.jit(jax.vmap(self.env(arena).step)))

    def many_resets(self, arena: str):
        """NavState [2048] of 2048 independent resets (one compile per arena); the first is
        ``reset(PRNGKey(3))``, the episode ``advisor-jax arena --seed 3`` writes."""
        keys = jax.random.split(jax.random.PRNGKey(42), 2048).at[0].set(jax.random.PRNGKey(3))
        return self._once("many_resets", arena, lambda: self.reset(arena)(keys))

    def sensors(self, arena: str):
        """(poses [B, 3], layouts [B, n, 5]) -> raw rangefinder readings [B, rays]."""
        env = self.env(arena)
        return self._once("sensors", arena, lambda: jax.jit(jax.vmap(env.sensor_readings)))

    def first_obs(self, arena: str):
        """(pose [3], goal [2], layout) -> observation [20] at rest (velocity 0)."""
        env = self.env(arena)

        def obs(pose, goal, layout):
            return env.observe(pose, goal, env.proximity(pose, layout), jnp.zeros(2))

        return self._once("first_obs", arena, lambda: jax.jit(obs))

    def place(self, arena: str, pose, goal, *, steps: int = 0, layout=None, key: int = 0):
        """A NavState with the robot at ``pose`` and the goal at ``goal``, mid-episode."""
        base = jax.tree_util.tree_map(lambda x: x[key], self.many_resets(arena))
        layout = base.layout if layout is None else jnp.asarray(layout, jnp.float32)
        pose = jnp.asarray(pose, jnp.float32)
        goal = jnp.asarray(goal, jnp.float32)
        obs = self.first_obs(arena)(pose, goal, layout)
        return base.replace(
            pose=pose,
            goal=goal,
            obs=obs,
            terminal_obs=obs,
            steps=jnp.int32(steps),
            layout=layout,
            running_return=jnp.float32(1.5),
        )

    def step_one(self, arena: str, state: NavState, action) -> NavState:
        """One step of one env through the session's compiled batched step."""
        batch = jax.tree_util.tree_map(lambda x: x[None], state)
        out = self.step(arena)(batch, jnp.asarray(action, jnp.float32)[None])
        return jax.tree_util.tree_map(lambda x: x[0], out)

    def cpu_readings(self, arena: str, pose, layout=None) -> np.ndarray:
        """Reference: CPU MuJoCo (``mj_forward``) readings at ``pose``."""
        env = self.env(arena)
        model = env.mj_model
        if layout is not None and env.procedural:
            model = mujoco.MjModel.from_xml_string(env.xml(np.asarray(layout)))
        data = mujoco.MjData(model)
        data.qpos[:] = np.asarray(pose, np.float64)
        mujoco.mj_forward(model, data)
        return np.array(data.sensordata)


@pytest.fixture(scope="session")
def sim() -> Sim:
    return Sim()
