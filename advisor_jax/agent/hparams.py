"""The vmappable hyperparameters, each declared once (``settings.hparam``): the RL learner's
and selector's (``HParams``) and each baseline's own (``LfdHParams``, ``McpHParams``).

Every field is a pytree leaf, so a grid of seeds × hyperparameters is one ``vmap`` over a
stacked struct and one compile. A paper agent's hyperparameters are an ``HParams``; a
baseline agent's are a ``BaselineHParams``: its RL learner's ``HParams`` and its prior
phases' own, nested. ``--hp`` / ``--grid`` name them flat (``demo_episodes``, not
``prior.demo_episodes``; ``settings.flat_fields``).

Defaults are the paper's simulation column (Tables A2, A4). Two readings of the paper are
ours (docs/architecture.md, "Paper readings"): the decay b = 0.15 of Table A2 cannot be per
episode (ε_st - bN would be negative after six episodes), so the default is 0.15 per 100
episodes, b = 0.0015; and the Ornstein–Uhlenbeck parameters, which the paper does not
give, default to θ = 0.15, σ = 0.1 (stationary std ≈ 0.19 in normalised action units).

Presets (``presets=``): ``physical`` is the paper's physical column (Tables A2, A4);
``quick`` shortens the schedules to the quick preset's 60 episodes; ``stable`` is ``paper``
with the three readings that 16 seeds per agent type support (docs/architecture.md
R33-R35): Â clipped to the action box with a scale-free step β = 1
(``results/afp_collapse/afp_collapse.md``) and the TD target clipped to the arena's return
bounds (``results/q_target_clip.md``). A baseline's episode counts take the advisor's
N_T of the preset (docs/baselines.md, "Rules shared by both baselines").
"""

from __future__ import annotations

import math
from typing import Any

from flax import struct

from advisor_jax.agent.advisor_quality import AdvisorQuality
from advisor_jax.agent.settings import flat_fields, flat_items, hparam

INF = math.inf


@struct.dataclass
class HParams:
    """Scalar hyperparameters of the RL learner, the selector and the noise; every field can
    differ across the agents of one vmap."""

    gamma: float = hparam(0.9, "γ, discount (Table A2)", low=0.0, high=1.0)
    tau: float = hparam(
        0.1, "τ, soft target update, Eqs. (6), (7)", low=0.0, high=1.0, low_closed=False,
        high_closed=True, freezes=True,
    )  # fmt: skip
    beta: float = hparam(0.01, "β, Eq. (2)", low=0.0, presets={"stable": 1.0})
    lr_actor: float = hparam(
        1e-5, "α_actor, Adam", low=0.0, low_closed=False, freezes=True,
        presets={"physical": 1e-4, "quick": 1e-3},
    )  # fmt: skip
    lr_critic: float = hparam(1e-3, "α_critic, Adam", low=0.0, low_closed=False, freezes=True)
    eps_start: float = hparam(
        0.85, "ε_st, Eq. (1)", low=0.0, high=1.0, high_closed=True, presets={"physical": 0.9}
    )
    eps_decay: float = hparam(
        0.0015, "b, Eq. (1), per episode (the paper's 0.15 read per 100)", low=0.0,
        presets={"physical": 0.001, "quick": 0.01},
    )  # fmt: skip
    advisor_episodes: float = hparam(
        250.0, "N_T, Eq. (1): the advisor is off once N > N_T", low=0.0,
        presets={"physical": 100.0, "quick": 30.0},
    )  # fmt: skip
    advisor_policy_episodes: float = hparam(
        1e9, "N_P (ours): AfP replaces Â only while N <= N_P; the paper replaces for the "
        "whole run, which the default (never reached) keeps", low=0.0,
    )  # fmt: skip
    ou_theta: float = hparam(0.15, "Ornstein–Uhlenbeck mean reversion", low=0.0)
    ou_sigma: float = hparam(0.1, "Ornstein–Uhlenbeck scale (normalised action units)", low=0.0)
    target_noise: float = hparam(
        0.1, "σ̄, TD3 target smoothing (Table A4)", low=0.0, presets={"physical": 0.05}
    )
    target_noise_clip: float = hparam(
        0.2, "c, TD3 target noise clip (Table A4)", low=0.0, presets={"physical": 0.1}
    )
    beta_normalize: float = hparam(
        0.0, "0: Eq. (2)'s step is β∇_aQ (paper); 1: scale-free, β/rms‖∇_aQ‖", low=0.0,
        high=1.0, high_closed=True, switch=True, presets={"stable": 1.0},
    )  # fmt: skip
    clip_actor_target: float = hparam(
        0.0, "0: Â as printed (paper); 1: Â clipped to the action box", low=0.0, high=1.0,
        high_closed=True, switch=True, presets={"stable": 1.0},
    )  # fmt: skip
    clip_q_target: float = hparam(
        0.0, "0: Q̂ as printed (paper); 1: Q̂ clipped to the arena's return bounds "
        "(envs.reward.return_bounds), against the single critic's overestimation runaway",
        low=0.0, high=1.0, high_closed=True, switch=True, presets={"stable": 1.0},
    )  # fmt: skip
    quality: AdvisorQuality = struct.field(pytree_node=True, default_factory=AdvisorQuality)
    """The advisor's quality knobs (``advisor_quality.py``): named flat, ``advisor_noise``."""


def _episodes(default: float, help: str, physical: float, quick: float):
    """A baseline's episode count: a whole number >= 1, counted in N_total."""
    return hparam(default, help, low=1.0, count=True,
                  presets={"physical": physical, "quick": quick})  # fmt: skip


def _bc_lr():
    return hparam(1e-3, "imitation learning rate (mbmf.py's 1e-3)", low=0.0, low_closed=False,
                  freezes=True)  # fmt: skip


@struct.dataclass
class LfdHParams:
    """LfD's own hyperparameters (docs/baselines.md, "LfD")."""

    demo_episodes: float = _episodes(250.0, "D: demonstration episodes", 100.0, 30.0)
    bc_lr: float = _bc_lr()


@struct.dataclass
class McpHParams:
    """MCP+MF's own hyperparameters (docs/baselines.md, "MCP + model-free")."""

    random_episodes: float = _episodes(50.0, "R: uniform-action episodes", 20.0, 6.0)
    mpc_episodes: float = _episodes(40.0, "M: MPC episodes per round", 16.0, 8.0)
    dagger_episodes: float = _episodes(10.0, "actor episodes per DAgger round", 4.0, 4.0)
    bc_lr: float = _bc_lr()
    model_lr: float = hparam(
        1e-3, "the dynamics model's Adam learning rate", low=0.0, low_closed=False,
        freezes=True,
    )  # fmt: skip
    model_noise: float = hparam(0.01, "input noise σ of the model fit (normalised units)", low=0.0)


@struct.dataclass
class BaselineHParams:
    """A baseline agent's hyperparameters: its RL learner's and its prior phases' own."""

    rl: HParams
    prior: Any  # LfdHParams or McpHParams


PRIOR_HPARAMS: dict[str, type] = {"lfd": LfdHParams, "mcp": McpHParams}
"""``BaselineConfig.kind`` -> the hyperparameters of its prior phases."""

HPARAM_NAMES: tuple[str, ...] = tuple(
    dict.fromkeys(n for cls in (HParams, *PRIOR_HPARAMS.values()) for n in flat_fields(cls()))
)
"""Every hyperparameter name ``--hp`` / ``--grid`` know (an agent type takes a subset)."""

HPARAM_DEFAULTS: dict[str, float] = {
    n: float(v) for cls in (HParams, *PRIOR_HPARAMS.values()) for n, v in flat_items(cls()).items()
}
"""The ``paper`` default of every hyperparameter name, by flat name."""

SWITCHES: tuple[str, ...] = tuple(n for n, (_, s) in flat_fields(HParams()).items() if s.switch)
"""The readings selectable per agent (0: the paper, 1: ours), traced like every
hyperparameter so that one sweep can hold both settings."""


def rl_hparams(hp: HParams | BaselineHParams) -> HParams:
    """The RL learner's hyperparameters of a paper or baseline agent."""
    return hp.rl if isinstance(hp, BaselineHParams) else hp
