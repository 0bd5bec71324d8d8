"""Policy specs of ``advisor-jax evaluate --policy``: the advisor, a run's agent, an export.

Errors name what was typed: ``--policy runs/x:5`` with two agents says "agent 5 is out of
range", a path that is not there "does not exist".
"""

from __future__ import annotations

import dataclasses
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
        from advisor_jax.training.run_state import read_run_json

        config = read_run_json(directory / "run.json").get("config") or {}
        return config.get("motion", "kinematic")  # brax runs' too; older runs: kinematic
    return None  # resolve_policy names the problem


@dataclasses.dataclass(frozen=True)
class RunSpec:
    """A ``RUN[:AGENT]`` spec: the run's directory, the agent, and how the run scored its
    agents (so that ``evaluate`` repeats eval.json by default)."""

    directory: Path
    index: int
    eval_seed: int  # run.json "eval_seed" (older runs: their first seed)
    eval_episodes: dict[str, int]  # {arena: episodes} of its eval.json
    max_episode_steps: int  # the h_max it trained and was evaluated with (0: the arena's)


def parse_policy(policy: str) -> RunSpec | Path | None:
    """``None`` for ``advisor``; the export directory; or a ``RunSpec``. ValueError naming
    the spec if it names nothing usable."""
    if policy == "advisor":
        return None
    path, sep, suffix = policy.rpartition(":")
    has_index = bool(sep) and suffix.isdigit()
    directory = Path(path if has_index else policy)
    if not directory.exists():
        raise ValueError(
            f"--policy {policy}: {directory} does not exist (give 'advisor', a training run "
            "directory RUN[:AGENT] or an export directory)"
        )
    if (directory / "policy.json").is_file():
        return directory
    if not (directory / "run.json").is_file():
        raise ValueError(
            f"--policy {policy}: {directory} is neither a training run (no run.json) nor an "
            "export (no policy.json)"
        )
    from advisor_jax.analysis.runs import own_eval_seed
    from advisor_jax.training.run_state import read_run_json

    summary = read_run_json(directory / "run.json")
    index = int(suffix) if has_index else 0
    n = len(summary["agents"])
    if index >= n:
        raise ValueError(
            f"--policy {policy}: agent {index} is out of range: {directory} has "
            f"{n} agent{'s' if n != 1 else ''} (0-{n - 1})"
        )
    evaluation = summary.get("evaluation") or {}
    return RunSpec(
        directory,
        index,
        own_eval_seed(summary),
        {arena: int(ev["episodes"]) for arena, ev in evaluation.items() if "episodes" in ev},
        int(summary["config"].get("max_episode_steps") or 0),
    )


def resolve_policy(policy: str, env) -> tuple[Callable[[Any, Any], Any], Any]:
    """``(policy_apply, params)`` for a policy spec; ``policy_apply(params, obs) -> action``.

    Specs: ``advisor`` (Algorithm A1 with the arena's T_o); ``RUN_DIR[:AGENT]``, the final
    policy of agent AGENT (default 0) of a training run (a brax agent's too);
    ``EXPORT_DIR``, an exported policy (verified like the car runner does).
    """
    spec = parse_policy(policy)
    if spec is None:
        from advisor_jax.agent.advisor import advisor_action, arena_advisor

        return (lambda params, obs: advisor_action(obs, params)), arena_advisor(env)
    if isinstance(spec, RunSpec):
        from advisor_jax.training.run_directory import load_agent_policy

        return load_agent_policy(spec.directory, spec.index)
    from advisor_jax.agent.networks import make_actor
    from advisor_jax.deploy.export import actor_params_from_policy
    from advisor_jax.runner.policy import load_policy

    loaded = load_policy(spec)
    # The arena runs with its own scales: an export made for others would be evaluated
    # as it never drives (a forged v_max = 5 m/s got the honest numbers).
    for name, unit in (("v_max", "m/s"), ("omega_max", "rad/s"), ("dt", "s")):
        exported, arena = getattr(loaded, name), getattr(env.config, name)
        if abs(exported - arena) > 1e-9:
            raise ValueError(
                f"{spec} was exported with {name}={exported:g} {unit} but the "
                f"arena uses {arena:g}: its evaluation here would not be how it drives"
            )
    params, hidden = actor_params_from_policy(loaded)
    return make_actor(hidden).apply, params
