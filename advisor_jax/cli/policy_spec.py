"""Policy specs of ``advisor-jax evaluate --policy``: the advisor, a run's agent, an export.

Errors name what was typed: ``--policy runs/x:5`` with two agents says "agent 5 is out of
range", a path that is not there "does not exist".
"""

from __future__ import annotations

import dataclasses
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


def resolve_policy(policy: str, env, advisor: str = "rule", quality=None) -> tuple[Any, Any]:
    """``(policy, params)`` for a policy spec, ``policy`` a ``PolicyApply`` or the advisor's
    ``StatefulPolicy`` (``evaluation.evaluate``), both for ``make_evaluate``.

    Specs: ``advisor``, the advisor ``advisor`` (``training/advisor_source``; default the
    paper's Algorithm A1 with the arena's T_o) under its quality knobs ``quality`` (an
    ``AdvisorQuality``; None: as it is); ``RUN_DIR[:AGENT]``, the final policy of agent AGENT
    (default 0) of a training run (a brax agent's too); ``EXPORT_DIR``, an exported policy
    (verified like the car runner does).
    """
    spec = parse_policy(policy)
    if spec is None:
        from advisor_jax.agent.advisor_quality import AdvisorQuality
        from advisor_jax.evaluation.evaluate import advisor_policy
        from advisor_jax.training.advisor_source import resolve_advisor

        resolved = resolve_advisor(advisor, env)
        return advisor_policy(resolved), quality if quality is not None else AdvisorQuality()
    if isinstance(spec, RunSpec):
        from advisor_jax.training.run_directory import load_agent_policy

        return load_agent_policy(spec.directory, spec.index)
    from advisor_jax.training.advisor_source import trained_policy

    apply, params, _ = trained_policy(str(spec), env)  # the export, verified
    return apply, params
