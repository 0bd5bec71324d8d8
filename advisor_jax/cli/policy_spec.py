"""Policy specs of ``advisor-jax evaluate --policy``: the advisor, a run's agent, an export."""

from __future__ import annotations

from typing import Any


def resolve_policy(policy: str, env, advisor: str = "rule", quality=None) -> tuple[Any, Any]:
    """``(policy, params)`` for a policy spec, ``policy`` a ``PolicyApply`` or the advisor's
    ``StatefulPolicy`` (``evaluation.evaluate``), both for ``make_evaluate``.

    Specs: ``advisor``, the advisor ``advisor`` (``training/advisor_source``; default the
    paper's Algorithm A1 with the arena's T_o) under its quality knobs ``quality`` (an
    ``AdvisorQuality``; None: as it is); ``RUN_DIR[:AGENT]``, the final actor of agent AGENT
    (default 0) of a training run; ``EXPORT_DIR``, an exported policy (verified like the car
    runner does).
    """
    from advisor_jax.training.advisor_source import resolve_advisor, trained_policy

    if policy == "advisor":
        from advisor_jax.agent.advisor_quality import AdvisorQuality
        from advisor_jax.evaluation.evaluate import advisor_policy

        resolved = resolve_advisor(advisor, env)
        return advisor_policy(resolved), quality if quality is not None else AdvisorQuality()
    found = trained_policy(policy, env)
    if found is None:
        raise ValueError(
            f"unknown policy {policy!r}: use 'advisor', a training run directory RUN[:AGENT] "
            "or an export directory (with policy.json)"
        )
    apply, params, _ = found
    return apply, params
