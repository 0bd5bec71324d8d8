"""Static settings of the paper's baselines (Table 1): LfD [59] and MCP + model-free [31]
(docs/baselines.md).

A baseline agent is the ``DDPG`` row (or ``TD3``, ``--baseline learner=td3``) preceded by
prior-knowledge phases that count against the same N_total episodes. This module holds what
is *static* about them (loop lengths and batch shapes: ``BaselineConfig``), parses
``--baseline KEY=VALUE`` and checks their *vmappable* settings (``hparams.LfdHParams``,
``hparams.McpHParams``) against the run's budget. The phases themselves live in
``training/prior/``.

Defaults (docs/baselines.md, "LfD", "MCP + model-free", "Rules shared by both baselines"):
imitation by ``bc_steps`` = 5,000 Adam steps of batch ``bc_batch`` = 512, then
``critic_warmup`` = 1,000 critic-only updates before the first actor update; MCP+MF's model
(500, 500) fitted ``model_steps`` = 3,000 steps of batch 512 per fit, random shooting with
K = 1,000 candidates over H = 20 steps, 4 MPC rounds and 4 DAgger rounds. The ``quick``
preset shrinks them. ``config`` imports this module.
"""

from __future__ import annotations

import dataclasses
import math
from collections.abc import Mapping, Sequence

import numpy as np

from advisor_jax.agent.hparams import PRIOR_HPARAMS
from advisor_jax.agent.settings import flat_fields, flat_items, setting, spec_of

# Agent name (as ``parse_agent`` accepts it, any case) -> BaselineConfig.kind.
BASELINE_AGENTS: dict[str, str] = {"lfd": "lfd", "mcp+mf": "mcp"}
# kind -> the agent's display name (``AgentConfig.name``).
BASELINE_NAMES: dict[str, str] = {"lfd": "LfD", "mcp": "MCP+MF"}
# Learners a baseline's RL phase may use (``AgentConfig.algo``): the shared rules' DDPG,
# or TD3 with Table A4's σ̄, c, d.
BASELINE_LEARNERS: tuple[str, ...] = ("ddpg", "td3")
# The hyperparameters only a baseline reads (``--hp`` / ``--grid`` refuse them otherwise).
BASELINE_HPARAMS: dict[str, tuple[str, ...]] = {
    kind: tuple(flat_fields(cls())) for kind, cls in PRIOR_HPARAMS.items()
}
MCP = ("mcp",)


def _is_int(value) -> bool:
    return not isinstance(value, bool) and isinstance(value, int | np.integer)


@dataclasses.dataclass(frozen=True)
class BaselineConfig:
    """Static settings of a baseline agent: the phases' loop lengths and batch sizes."""

    kind: str = "lfd"
    """Which baseline: lfd (Pfeiffer et al.: demonstrations, imitation, then RL) or mcp
    (Nagabandi et al.: random data, model, MPC rounds, imitation of the MPC, DAgger, RL)."""
    bc_steps: int = setting(5000, presets={"quick": 200})
    """Imitation: Adam steps of the actor on the demonstrations (one per scan step)."""
    bc_batch: int = setting(512, presets={"quick": 128})
    """Imitation minibatch (``mbmf.py``'s 512)."""
    critic_warmup: int = setting(1000, presets={"quick": 100})
    """Critic-only updates after imitation, before the first actor update (0: none, the
    sources' literal reading)."""
    model_hidden: tuple[int, ...] = setting((500, 500), presets={"quick": (64, 64)}, only=MCP)
    """MCP+MF: the dynamics model's hidden widths."""
    model_steps: int = setting(3000, presets={"quick": 200}, only=MCP)
    """MCP+MF: Adam steps of each model fit (after the random data and each MPC round)."""
    model_batch: int = setting(512, presets={"quick": 128}, only=MCP)
    """MCP+MF: model minibatch."""
    mpc_horizon: int = setting(20, presets={"quick": 5}, only=MCP)
    """MCP+MF: H, steps of each random-shooting candidate (1.0 s)."""
    mpc_candidates: int = setting(1000, presets={"quick": 64}, only=MCP)
    """MCP+MF: K, candidate action sequences per control step."""
    mpc_rounds: int = setting(4, presets={"quick": 2}, only=MCP)
    """MCP+MF: rounds of ``mpc_episodes`` MPC episodes, each followed by a model refit."""
    dagger_rounds: int = setting(4, presets={"quick": 2}, only=MCP)
    """MCP+MF: rounds of ``dagger_episodes`` actor episodes labelled by the MPC, each followed
    by a refit of the actor (0: imitation of the MPC rounds only)."""

    def __post_init__(self):
        if self.kind not in BASELINE_NAMES:
            raise ValueError(
                f"unknown baseline kind {self.kind!r}; choose one of {', '.join(BASELINE_NAMES)}"
            )
        for name in ("bc_steps", "bc_batch", "model_steps", "model_batch", "mpc_horizon",
                     "mpc_candidates", "mpc_rounds"):  # fmt: skip
            value = getattr(self, name)
            if not _is_int(value) or value <= 0:
                raise ValueError(f"baseline setting {name} must be a positive integer, got {value}")
        for name in ("critic_warmup", "dagger_rounds"):
            value = getattr(self, name)
            if not _is_int(value) or value < 0:
                raise ValueError(f"baseline setting {name} must be an integer >= 0, got {value}")
        hidden = self.model_hidden
        if isinstance(hidden, int | str) or not hidden:
            raise ValueError(f"baseline setting model_hidden must be widths like 500,500, got "
                             f"{hidden!r}")  # fmt: skip
        hidden = tuple(hidden)  # a list from run.json
        if any(not _is_int(w) or w <= 0 for w in hidden):
            raise ValueError(f"baseline setting model_hidden must be positive widths, got "
                             f"{','.join(map(str, hidden))}")  # fmt: skip
        object.__setattr__(self, "model_hidden", tuple(int(w) for w in hidden))

    @property
    def name(self) -> str:
        return BASELINE_NAMES[self.kind]


# ``--baseline KEY=VALUE``: the keys each kind knows (``setting``'s ``only``). ``learner``
# sets AgentConfig.algo.
BASELINE_KEYS: dict[str, tuple[str, ...]] = {
    kind: ("learner", *(f.name for f in dataclasses.fields(BaselineConfig)
                        if spec_of(f) and (not spec_of(f).only or kind in spec_of(f).only)))
    for kind in BASELINE_NAMES
}  # fmt: skip


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
        if key == "model_hidden":
            try:
                settings[key] = tuple(int(w) for w in value.split(","))
            except ValueError:
                raise ValueError(
                    f"baseline setting model_hidden={value!r} must be integer widths, e.g. 500,500"
                ) from None
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
        raise ValueError(
            "a baseline agent takes no advisor switches (AfD, AfP): use "
            f"{' or '.join(map(repr, BASELINE_NAMES.values()))}"
        )


def prior_episodes(settings: BaselineConfig, hp) -> np.ndarray:
    """Episodes the baseline's phases before RL take, per stacked agent (float64 [agents]);
    ``hp``: the agents' ``BaselineHParams`` (or their flat values)."""
    values = hp if isinstance(hp, Mapping) else flat_items(hp)
    count = lambda name: np.atleast_1d(np.asarray(values[name], np.float64))  # noqa: E731
    if settings.kind == "lfd":
        return count("demo_episodes")
    return (count("random_episodes") + settings.mpc_rounds * count("mpc_episodes")
            + settings.dagger_rounds * count("dagger_episodes"))  # fmt: skip


def unread_hparams(kind: str | None) -> set[str]:
    """The baselines' hyperparameters an agent of baseline ``kind`` (None: a paper type)
    does not read: every one for the paper's types, MCP+MF's for LfD, LfD's for MCP+MF."""
    own = BASELINE_HPARAMS.get(kind, ())
    return {n for names in BASELINE_HPARAMS.values() for n in names} - set(own)


def check_hparam_names(
    settings: BaselineConfig | None, names: Sequence[str], agent: str = ""
) -> None:
    """Refuses a baseline's hyperparameter (``--hp`` / ``--grid``) for an agent that does not
    read it, naming the agents that do."""
    used = sorted(set(names) & unread_hparams(None if settings is None else settings.kind))
    if used:
        what = ("is not a baseline" if settings is None
                else f"is {settings.name}, which does not read it")  # fmt: skip
        readers = [BASELINE_NAMES[k] for k, ns in BASELINE_HPARAMS.items() if used[0] in ns]
        raise ValueError(
            f"unknown baseline setting {', '.join(used)}: agent {agent!r} {what} (only "
            f"{', '.join(readers)} read it)"
        )


def check_baseline_hparams(
    settings: BaselineConfig | None, episodes: int, hp, grid: Mapping | None = None,
    agent: str = "",
) -> None:  # fmt: skip
    """The vmappable settings against the budget, per stacked agent.

    ``settings``: the agent's ``BaselineConfig``, None for the paper's agents; ``hp``: its
    hyperparameters (a baseline's ``BaselineHParams``). Each episode count (declared
    ``count``) must be a whole number >= 1 and the prior phases together below N_total: the
    RL phase needs at least one episode. A grid over a baseline hyperparameter is refused
    for an agent that does not read it.
    """
    check_hparam_names(settings, list(grid or ()), agent)
    if settings is None:
        return
    fields, values = flat_fields(hp), flat_items(hp)
    for name in BASELINE_HPARAMS[settings.kind]:
        if not fields[name][1].count:
            continue
        column = np.atleast_1d(np.asarray(values[name], np.float64))
        for i, d in enumerate(column):
            where = f" (agent {i})" if column.size > 1 else ""
            if not (math.isfinite(d) and d == round(d) and d >= 1):
                raise ValueError(f"{name}={d:g}{where} must be a whole number >= 1")
    total = prior_episodes(settings, values)
    for i, d in enumerate(total):
        where = f" (agent {i})" if total.size > 1 else ""
        if d < episodes:
            continue
        if settings.kind == "lfd":
            raise ValueError(
                f"demo_episodes={d:g}{where} must be below episodes={episodes} (N_total): the "
                "demonstrations count against the budget and RL needs at least one episode; "
                "lower demo_episodes or raise --episodes"
            )
        picked = {}
        for name in ("random_episodes", "mpc_episodes", "dagger_episodes"):
            column = np.atleast_1d(np.asarray(values[name], np.float64))
            picked[name] = column[min(i, column.size - 1)]
        raise ValueError(
            f"random_episodes + mpc_rounds·mpc_episodes + dagger_rounds·dagger_episodes = "
            f"{picked['random_episodes']:g} + {settings.mpc_rounds}·{picked['mpc_episodes']:g} + "
            f"{settings.dagger_rounds}·{picked['dagger_episodes']:g} = {d:g}{where} must be "
            f"below episodes={episodes} (N_total): every MCP+MF episode counts against the "
            "budget and RL needs at least one; lower them or raise --episodes"
        )
