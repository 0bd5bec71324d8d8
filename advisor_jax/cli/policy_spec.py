"""Policy specs of ``advisor-jax evaluate --policy``: the advisor, a run's agent, an export."""

from __future__ import annotations

from collections.abc import Callable
from pathlib import Path
from typing import Any


def policy_motion(policy: str) -> str | None:
    """The motion setting a policy was trained with: a run's ``TrainConfig.motion``, an
    export's ``env.motion`` (kinematic for those written before the motion models); None
    for the advisor, which is not trained."""
    if policy == "advisor":
        return None
    path, sep, suffix = policy.rpartition(":")
    directory = Path(path if sep and suffix.isdigit() else policy)
    if (directory / "policy.json").is_file():
        from advisor_jax.runner.policy import load_policy

        return load_policy(directory).env.get("motion", "kinematic")
    if (directory / "run.json").is_file():
        from advisor_jax.training.run_directory import load_run

        return load_run(directory)[0].motion
    return None  # resolve_policy names the problem


def resolve_policy(policy: str, env) -> tuple[Callable[[Any, Any], Any], Any]:
    """``(policy_apply, params)`` for a policy spec; ``policy_apply(params, obs) -> action``.

    Specs: ``advisor`` (Algorithm A1 with the arena's T_o); ``RUN_DIR[:AGENT]``, the final
    actor of agent AGENT (default 0) of a training run; ``EXPORT_DIR``, an exported policy
    (verified like the car runner does).
    """
    if policy == "advisor":
        from advisor_jax.agent.advisor import advisor_action, arena_advisor

        return (lambda params, obs: advisor_action(obs, params)), arena_advisor(env)
    from advisor_jax.agent.networks import make_actor

    path, sep, suffix = policy.rpartition(":")
    has_index = bool(sep) and suffix.isdigit()
    index = int(suffix) if has_index else 0
    directory = Path(path if has_index else policy)
    if (directory / "policy.json").is_file():
        from advisor_jax.deploy.export import actor_params_from_policy
        from advisor_jax.runner.policy import load_policy

        loaded = load_policy(directory)
        # The arena runs with its own scales: an export made for others would be evaluated
        # as it never drives (a forged v_max = 5 m/s got the honest numbers).
        for name, unit in (("v_max", "m/s"), ("omega_max", "rad/s"), ("dt", "s")):
            exported, arena = getattr(loaded, name), getattr(env.config, name)
            if abs(exported - arena) > 1e-9:
                raise ValueError(
                    f"{directory} was exported with {name}={exported:g} {unit} but the "
                    f"arena uses {arena:g}: its evaluation here would not be how it drives"
                )
        params, hidden = actor_params_from_policy(loaded)
        return make_actor(hidden).apply, params
    if (directory / "run.json").is_file():
        from advisor_jax.training.run_directory import load_actor

        cfg, _, params = load_actor(directory, index)
        return make_actor(cfg.agent.actor_hidden).apply, params
    raise ValueError(
        f"unknown policy {policy!r}: use 'advisor', a training run directory RUN[:AGENT] "
        "or an export directory (with policy.json)"
    )
