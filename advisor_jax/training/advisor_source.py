"""Where an advisor comes from: ``--advisor SPEC`` resolved for an arena, and its identity.

    SPEC                   advisor
    rule                   the paper's Algorithm A1 with the arena's T_o (the default)
    NAME                   a name given to ``agent.advisors.register_advisor``
    MODULE:FUNCTION        a function (params, obs) -> action or an ``AdvisorPlugin``
    RUN[:INDEX]            the final actor of agent INDEX (default 0) of a finished run
    EXPORT_DIR             an exported policy (policy.json; verified like the car does)

A trained policy is any actor: e.g. a DDPG actor after 100 episodes advising a new agent.
``resolve_advisor`` checks a user's function (``advisors.check_advisor``: jittable, one
action of shape (2,), finite on the arena's start observations) before anything compiles.
``Advisor.record()`` is the identity run.json keeps (spec, kind, parameters' sha256, the
function's source sha256, a trained policy's origin); ``run_state.check_same_advisor``
refuses to resume a run whose advisor has changed since.
"""

from __future__ import annotations

import functools
from collections.abc import Callable
from pathlib import Path
from typing import Any

import jax
import numpy as np

from advisor_jax.agent.advisors import (
    Advisor,
    check_advisor,
    plugin_for,
    registered_names,
    resolve_plugin,
)

SPEC_HELP = (
    "rule (the paper's Algorithm A1), a registered name, MODULE:FUNCTION, a training run "
    "RUN[:AGENT] or an export directory"
)


def trained_policy(spec: str, env) -> tuple[Callable, Any, dict] | None:
    """``(apply, params, origin)`` of a trained actor named by ``spec`` (``RUN[:INDEX]`` or an
    export directory); None if ``spec`` names no directory."""
    path, sep, suffix = spec.rpartition(":")
    has_index = bool(sep) and suffix.isdigit()
    index = int(suffix) if has_index else 0
    directory = Path(path if has_index else spec)
    if not directory.is_dir():
        return None
    from advisor_jax.agent.networks import make_actor

    if (directory / "policy.json").is_file():
        from advisor_jax.deploy.export import actor_params_from_policy
        from advisor_jax.runner.policy import load_policy

        loaded = load_policy(directory)
        # The arena runs with its own scales: an export made for others would act here as it
        # never drives (a forged v_max = 5 m/s got the honest numbers).
        for name, unit in (("v_max", "m/s"), ("omega_max", "rad/s"), ("dt", "s")):
            exported, arena = getattr(loaded, name), getattr(env.config, name)
            if abs(exported - arena) > 1e-9:
                raise ValueError(
                    f"{directory} was exported with {name}={exported:g} {unit} but the "
                    f"arena uses {arena:g}: it would not act here as it drives"
                )
        params, hidden = actor_params_from_policy(loaded)
        origin = {"kind": "export", "weights_sha256": loaded.meta.get("weights_sha256")}
        return make_actor(hidden).apply, params, origin
    if (directory / "run.json").is_file():
        from advisor_jax.training.run_directory import load_actor

        cfg, row, params = load_actor(directory, index)
        origin = {"kind": "run", "agent": cfg.agent.name, "index": index, "seed": row["seed"]}
        return make_actor(cfg.agent.actor_hidden).apply, params, origin
    return None


def resolve_advisor(spec: str, env, check: bool = True) -> Advisor:
    """The advisor ``spec`` names (module docstring), for arena ``env``; ValueError naming
    the spec and the forms it may take. ``check``: run ``check_advisor`` on a user's
    function (built-in and trained ones are known to be well formed)."""
    spec = spec.strip() if isinstance(spec, str) else spec
    if not spec:
        raise ValueError(f"--advisor is empty: give {SPEC_HELP}")
    found = plugin_for(spec)
    if found is not None:
        plugin, kind, source = found
        advisor = Advisor(spec, kind, plugin.apply, resolve_plugin(plugin, env), source)
        if check and kind != "builtin":
            check_advisor(advisor, sample_observations(env))
        return advisor
    policy = trained_policy(spec, env)
    if policy is None:
        raise ValueError(
            f"unknown advisor {spec!r}: give {SPEC_HELP} (registered: "
            f"{', '.join(registered_names())})"
        )
    apply, params, origin = policy
    return Advisor(spec, origin.pop("kind"), apply, params, origin=origin)


@functools.lru_cache(maxsize=8)
def _starts(arena: str, max_episode_steps: int) -> np.ndarray:
    import envs
    from advisor_jax.training.population import seed_key

    env = envs.make_env(arena, max_episode_steps=max_episode_steps)
    states = jax.jit(jax.vmap(env.reset))(jax.random.split(seed_key(0), 64))
    return np.asarray(states.obs)


def sample_observations(env) -> np.ndarray:
    """[n, 20] observations to try an advisor on: 64 of the arena's starts, and the extremes
    (every sensor touching, nothing in range; the goal behind, ahead, reached)."""
    starts = _starts(env.arena_name, int(env.max_episode_steps))
    extremes = np.zeros((6, starts.shape[1]), np.float32)
    extremes[:, :16] = [[0.0], [1.0], [0.05], [1.0], [0.5], [1.0]]
    extremes[:, 16] = [np.pi - 1e-3, -np.pi, 0.0, 0.0, 1.0, 0.0]
    extremes[:, 17] = [0.0, 7.0, 1.0, 0.0, 2.0, 1e-6]
    return np.concatenate([starts, extremes])
