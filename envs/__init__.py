"""MJX navigation arenas of the paper (§5.1, §5.2) and a registry to build them.

    env = envs.make_env("training", omega_max=2.0)   # NavEnv
    env = envs.make_env("training", motion="mjx")    # the robot's motion simulated by MJX
    state = env.reset(key); state = env.step(state, action)

``envs.make_brax_env(arena, ...)`` gives the same arena as a ``brax.envs.Env`` for brax's
wrappers and trainers (``envs/brax_env.py``; brax is imported only then).

Arenas: ``training`` and ``validation`` (5 m × 5 m, Fig. 2), ``physical`` (4.9 m × 3 m,
200-beam lidar reduced to 16 zones) and ``procedural`` (a new random layout per episode).
Motion models (``motion.py``): ``kinematic`` (a unicycle, the default) and ``mjx`` (a
Pioneer 3-DX body and wheels stepped by ``mjx.step``), for every arena.
"""

from __future__ import annotations

import dataclasses

from envs.layouts import ARENA_SPECS
from envs.motion import MOTION_MODELS, DriveParams, parse_motion
from envs.navigation import (
    COLLISION,
    GOAL,
    OUTCOME_NAMES,
    RUNNING,
    TIMEOUT,
    EnvConfig,
    NavEnv,
    NavState,
)

ARENAS: tuple[str, ...] = tuple(ARENA_SPECS)


def make_env(arena: str, motion: str = "kinematic", **config_overrides) -> NavEnv:
    """Builds the named arena. ``motion``: the motion setting, ``kinematic``, ``mjx`` or
    ``mjx:KEY=VALUE,...`` (``motion.parse_motion``); keyword arguments override the other
    ``EnvConfig`` fields."""
    if arena not in ARENA_SPECS:
        raise ValueError(f"unknown arena {arena!r}; choose one of {', '.join(ARENAS)}")
    fields = {f.name for f in dataclasses.fields(EnvConfig)}
    unknown = sorted(set(config_overrides) - fields)
    if unknown:
        raise ValueError(
            f"unknown EnvConfig field(s) {', '.join(unknown)}; valid: {', '.join(sorted(fields))}"
        )
    settings = parse_motion(motion)
    twice = sorted(set(settings) & set(config_overrides))
    if twice:
        raise ValueError(
            f"{', '.join(twice)} given both in motion={motion!r} and as a keyword; give it once"
        )
    return NavEnv(arena, EnvConfig(**settings, **config_overrides))


def make_brax_env(arena: str, **config_overrides):
    """``make_env(arena, **config_overrides)`` as a ``brax.envs.Env`` (``envs/brax_env.py``;
    imports brax). ``max_episode_steps`` (h_max, 0: the arena's) becomes its
    ``episode_length``, the limit to give brax's EpisodeWrapper; the NavEnv inside runs
    without a time limit of its own."""
    from envs.brax_env import NO_TIME_LIMIT, BraxNavEnv

    h_max = config_overrides.pop("max_episode_steps", 0)
    if isinstance(h_max, bool) or not isinstance(h_max, int) or h_max < 0:
        raise ValueError(f"max_episode_steps must be an integer >= 0, got {h_max!r}")
    nav = make_env(arena, max_episode_steps=NO_TIME_LIMIT, **config_overrides)
    return BraxNavEnv(nav, h_max or ARENA_SPECS[arena].h_max)


__all__ = [
    "ARENAS", "COLLISION", "GOAL", "MOTION_MODELS", "OUTCOME_NAMES", "RUNNING", "TIMEOUT",
    "DriveParams", "EnvConfig", "NavEnv", "NavState", "make_brax_env", "make_env", "parse_motion",
]  # fmt: skip
