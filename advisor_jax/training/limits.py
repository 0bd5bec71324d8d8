"""Limits on the sizes a run may ask for, checked before anything is written or compiled.

Counts end up in int32 counters (environment steps, episode indices) and in arrays held by
the devices. A count past what they hold used to pass validation, write run.json, compile
and then fail with OverflowError (``--episodes 1000000000000``), or allocate until the
kernel killed the process (``--episodes 2147483648``). Each limit below is refused by name:

    episodes per agent                    <= MAX_EPISODES (the paper trains 500-1000)
    agents (seeds x grid points)          <= MAX_AGENTS
    environment steps per agent           <= MAX_STEPS - chunk_steps (int32 step counters;
                                             ceil(episodes / envs) x h_max + offline steps)
    evaluation episodes (per arena)       <= MAX_EVAL_EPISODES, and agents x episodes <=
                                             MAX_PARALLEL_EPISODES (they run side by side)
    the population's training state       <= the memory of the devices that hold it
      (replay buffers, episode logs, networks: jax.eval_shape of init, nothing allocated)
"""

from __future__ import annotations

import math
import os

import jax
import numpy as np

MAX_EPISODES = 10_000_000
MAX_AGENTS = 65_536
MAX_STEPS = 2**31 - 1
MAX_EVAL_EPISODES = 1_000_000
MAX_PARALLEL_EPISODES = 2**24


def check_count(name: str, value: int, maximum: int, why: str) -> int:
    """``value`` if 1 <= value <= maximum, else ValueError naming the option and the limit."""
    if isinstance(value, bool) or not isinstance(value, int | np.integer) or value < 1:
        raise ValueError(f"{name} must be a positive integer, got {value!r}")
    if value > maximum:
        raise ValueError(f"{name} {value:,} is above the limit of {maximum:,} ({why})")
    return int(value)


def check_agents(n_agents: int) -> int:
    return check_count("the population", n_agents, MAX_AGENTS, "seeds x grid points, agents")


def check_episodes(episodes: int) -> int:
    return check_count("--episodes", episodes, MAX_EPISODES, "training episodes per agent")


def check_eval_episodes(episodes: int, n_agents: int = 1, option="--eval-episodes") -> int:
    """Evaluation episodes per arena of ``n_agents`` agents, all run side by side."""
    check_count(option, episodes, MAX_EVAL_EPISODES, "evaluation episodes per arena")
    if episodes * n_agents > MAX_PARALLEL_EPISODES:
        raise ValueError(
            f"{option} {episodes:,} x {n_agents:,} agents = {episodes * n_agents:,} episodes "
            f"run side by side, above the limit of {MAX_PARALLEL_EPISODES:,}"
        )
    return episodes


def check_steps(max_steps: int, chunk_steps: int) -> None:
    """Environment steps per agent, counted in int32 (the last chunk may overshoot)."""
    if max_steps + chunk_steps > MAX_STEPS:
        raise ValueError(
            f"this run needs up to {max_steps:,} environment steps per agent (episodes x h_max "
            f"/ envs per agent, plus {chunk_steps:,} for the last chunk), above the limit of "
            f"{MAX_STEPS:,} (2^31 - 1: step counters are 32-bit); lower --episodes or "
            "--max-episode-steps"
        )


def state_bytes(abstract_state) -> int:
    """Bytes of a (shape-only) pytree."""
    leaves = jax.tree_util.tree_leaves(abstract_state)
    return sum(math.prod(x.shape) * np.dtype(x.dtype).itemsize for x in leaves)


def device_memory(n_devices: int) -> int | None:
    """Bytes of memory on ``n_devices`` of JAX's default devices (host memory for the CPU),
    or None where it cannot be told."""
    device = jax.devices()[0]
    if device.platform == "cpu":
        try:
            return os.sysconf("SC_PAGE_SIZE") * os.sysconf("SC_PHYS_PAGES")
        except (ValueError, OSError):
            return None
    stats = device.memory_stats() or {}
    limit = stats.get("bytes_limit")
    return None if limit is None else int(limit) * n_devices


def check_state_fits(abstract_state, n_devices: int, n_padded: int, n_agents: int) -> None:
    """The population's training state (padded to ``n_padded`` agents) must fit the memory
    of the ``n_devices`` that hold it; the program needs more, so this refuses only what
    can never run."""
    needed = state_bytes(abstract_state) * n_padded // max(n_agents, 1)
    available = device_memory(n_devices)
    if available is not None and needed > available:
        raise ValueError(
            f"the training state of {n_agents:,} agents needs {needed / 2**30:,.1f} GiB "
            f"(replay buffers, episode logs, networks), more than the {available / 2**30:,.1f} "
            f"GiB of memory of the {n_devices} {jax.devices()[0].platform.upper()} device(s) "
            "that would hold it; lower --episodes, --buffer-size, --envs-per-agent or the "
            "number of agents"
        )
