"""Static settings of the paper's baselines (Table 1): LfD [59] (docs/baselines.md).

A baseline agent is the ``DDPG`` row (or ``TD3``, ``--baseline learner=td3``) preceded by
prior-knowledge phases that count against the same N_total episodes. This module holds what
is *static* about them (loop lengths and batch shapes: ``BaselineConfig``), parses
``--baseline KEY=VALUE`` and checks the *vmappable* settings (``HParams.demo_episodes``,
``bc_lr``) against the run's budget. The phases themselves live in
``training/phases.py`` (the hook) and ``training/lfd.py`` (LfD's phases).

Defaults (docs/baselines.md, "LfD", "Rules shared by both baselines"): imitation by
``bc_steps`` = 5,000 Adam steps of batch ``bc_batch`` = 512 on the demonstrations, then
``critic_warmup`` = 1,000 critic-only updates before the first actor update; the ``quick``
preset shrinks them (200, 128, 100). Only ``dataclasses`` and the standard library here:
``config`` imports this module.
"""

from __future__ import annotations

import dataclasses
import math
from collections.abc import Mapping, Sequence

import numpy as np

# Agent name (as ``parse_agent`` accepts it, any case) -> BaselineConfig.kind.
BASELINE_AGENTS: dict[str, str] = {"lfd": "lfd"}
# kind -> the agent's display name (``AgentConfig.name``).
BASELINE_NAMES: dict[str, str] = {"lfd": "LfD"}
# Learners a baseline's RL phase may use (``AgentConfig.algo``): the shared rules' DDPG,
# or TD3 with Table A4's σ̄, c, d.
BASELINE_LEARNERS: tuple[str, ...] = ("ddpg", "td3")
# HParams fields that only a baseline reads (``--hp`` / ``--grid`` refuse them otherwise).
BASELINE_HPARAMS: dict[str, tuple[str, ...]] = {"lfd": ("demo_episodes", "bc_lr")}
# Per-preset overrides of BaselineConfig (docs/baselines.md, "Fitting the code base").
BASELINE_PRESETS: dict[str, dict] = {
    "paper": {},
    "stable": {},
    "physical": {},
    "quick": dict(bc_steps=200, bc_batch=128, critic_warmup=100),
}


@dataclasses.dataclass(frozen=True)
class BaselineConfig:
    """Static settings of a baseline agent: the phases' loop lengths and batch sizes."""

    kind: str = "lfd"
    """Which baseline: lfd (Pfeiffer et al.: demonstrations, imitation, then RL)."""
    bc_steps: int = 5000
    """Imitation: Adam steps of the actor on the demonstrations (one per scan step)."""
    bc_batch: int = 512
    """Imitation minibatch (``mbmf.py``'s 512)."""
    critic_warmup: int = 1000
    """Critic-only updates after imitation, before the first actor update (0: none, the
    sources' literal reading)."""

    def __post_init__(self):
        if self.kind not in BASELINE_NAMES:
            raise ValueError(
                f"unknown baseline kind {self.kind!r}; choose one of {', '.join(BASELINE_NAMES)}"
            )
        for name in ("bc_steps", "bc_batch"):
            value = getattr(self, name)
            if isinstance(value, bool) or not isinstance(value, int | np.integer) or value <= 0:
                raise ValueError(f"baseline setting {name} must be a positive integer, got {value}")
        value = self.critic_warmup
        if isinstance(value, bool) or not isinstance(value, int | np.integer) or value < 0:
            raise ValueError(f"baseline setting critic_warmup must be an integer >= 0, got {value}")

    @property
    def name(self) -> str:
        return BASELINE_NAMES[self.kind]


# ``--baseline KEY=VALUE``: the keys each kind knows. ``learner`` sets AgentConfig.algo.
_FIELDS = tuple(f.name for f in dataclasses.fields(BaselineConfig) if f.name != "kind")
BASELINE_KEYS: dict[str, tuple[str, ...]] = {"lfd": ("learner", *_FIELDS)}


def parse_baseline_settings(items: Sequence[str], kind: str | None, agent: str) -> dict:
    """``["learner=td3", "bc_steps=300"]`` -> ``{"learner": "td3", "bc_steps": 300}``.

    ``kind`` is the agent's baseline kind (None: not a baseline, and any setting is refused).
    Raises ValueError naming the item, the known keys and the fix.
    """
    settings: dict = {}
    for item in items:
        key, sep, value = item.partition("=")
        key, value = key.strip(), value.strip()
        if not sep or not value:
            raise ValueError(f"--baseline expects KEY=VALUE, got {item!r}")
        if kind is None:
            raise ValueError(
                f"unknown baseline setting {key!r}: agent {agent!r} is not a baseline "
                f"(--baseline is for {', '.join(BASELINE_NAMES.values())})"
            )
        known = BASELINE_KEYS[kind]
        if key not in known:
            raise ValueError(
                f"unknown baseline setting {key!r} for {BASELINE_NAMES[kind]}; "
                f"choose from {', '.join(known)}"
            )
        if key in settings:
            raise ValueError(f"--baseline sets {key} twice; give it once")
        if key == "learner":
            settings[key] = value.lower()
            continue
        try:
            settings[key] = int(value)
        except ValueError:
            raise ValueError(f"baseline setting {key}={value!r} must be an integer") from None
    return settings


def check_baseline_learner(algo: str, advisor_data: bool, advisor_policy: bool) -> None:
    """A baseline's RL phase is plain DDPG or TD3: no AfD, no AfP (docs/baselines.md)."""
    if algo not in BASELINE_LEARNERS:
        raise ValueError(
            f"baseline setting learner={algo!r} is not allowed; choose one of "
            f"{', '.join(BASELINE_LEARNERS)}"
        )
    if advisor_data or advisor_policy:
        raise ValueError("a baseline agent takes no advisor switches (AfD, AfP): use 'LfD'")


def check_baseline_hparams(
    kind: str | None, episodes: int, hp, grid: Mapping | None = None, agent: str = ""
) -> None:
    """The vmappable settings against the budget, per stacked agent.

    ``demo_episodes`` must be a whole number in [1, N_total): the RL phase needs at least
    one episode. A grid over a baseline HParam is refused for a non-baseline agent.
    """
    if kind is None:
        used = sorted(set(grid or ()) & {n for ns in BASELINE_HPARAMS.values() for n in ns})
        if used:
            raise ValueError(
                f"unknown baseline setting {', '.join(used)}: agent {agent!r} is not a "
                f"baseline (only {', '.join(BASELINE_NAMES.values())} read it)"
            )
        return
    values = np.atleast_1d(np.asarray(hp.demo_episodes, np.float64))
    for i, d in enumerate(values):
        where = f" (agent {i})" if values.size > 1 else ""
        if not (math.isfinite(d) and d == round(d) and d >= 1):
            raise ValueError(f"demo_episodes={d:g}{where} must be a whole number >= 1")
        if d >= episodes:
            raise ValueError(
                f"demo_episodes={d:g}{where} must be below episodes={episodes} (N_total): the "
                "demonstrations count against the budget and RL needs at least one episode; "
                "lower demo_episodes or raise --episodes"
            )
