"""Configuration: static shapes and switches vs. vmappable scalar hyperparameters.

Two kinds of configuration (docs/architecture.md, "Configuration"):

* ``AgentConfig`` / ``TrainConfig`` are frozen dataclasses of *static* values: anything that
  fixes a shape, a loop length or a code path (network sizes, buffer and batch sizes, the
  algorithm and advisor switches, the TD3 delay d). Changing one recompiles.
* ``HParams`` is a ``flax.struct`` dataclass of *scalars* (γ, τ, β, learning rates, ε_st,
  b, N_T, noise scales). Every field is a pytree leaf, so a grid of seeds × hyperparameters
  is one ``vmap`` over a stacked ``HParams`` and one compile.

Defaults are the paper's simulation column (Tables A2, A4). Two readings of the paper are
ours (docs/architecture.md, "Paper readings"): the decay b = 0.15 of Table A2 cannot be per
episode (ε_st - bN would be negative after six episodes), so the default is 0.15 per 100
episodes, b = 0.0015; and the Ornstein–Uhlenbeck parameters, which the paper does not
give, default to θ = 0.15, σ = 0.1 (stationary std ≈ 0.19 in normalised action units; a
larger σ made the noisy advisor collide more; README, "How we read the paper").
"""

from __future__ import annotations

import dataclasses
import math
from typing import Literal

import numpy as np
from flax import struct

from advisor_jax.agent.baselines import (
    BASELINE_AGENTS,
    BASELINE_KEYS,
    BASELINE_NAMES,
    BASELINE_PRESETS,
    BaselineConfig,
    check_baseline_learner,
)
from advisor_jax.contract import spec

Algo = Literal["ddpg", "addpg", "td3", "atd3"]
ALGOS: tuple[str, ...] = ("ddpg", "addpg", "td3", "atd3")
PRECISION_NAMES: tuple[str, ...] = ("fp32", "bf16")


def _positive(name: str, value: int) -> None:
    if int(value) <= 0:
        raise ValueError(f"{name} must be a positive integer, got {value}")


@dataclasses.dataclass(frozen=True)
class AgentConfig:
    """Static description of one agent type (shapes and code paths)."""

    algo: Algo = "atd3"
    """Learner: ddpg / td3 use the deterministic policy gradient; addpg / atd3 use the
    target Â = π(S) + β∇_aQ with an MSE actor loss (Alg. 2 / A3)."""
    advisor_data: bool = True
    """AfD: the advisor takes part in data collection through the Eq. 1 selector."""
    advisor_policy: bool = True
    """AfP: the advisor replaces Â per sample where the critic rates it higher (Alg. 2
    steps 11-13). Only for addpg / atd3."""
    actor_hidden: tuple[int, ...] = (600, 300)
    """Actor hidden widths (paper: 600, 300 → 193,502 parameters)."""
    critic_state_hidden: int = 1000
    """Critic width of the state-only first layer (paper: 1000)."""
    critic_hidden: tuple[int, ...] = (500, 600)
    """Critic widths after the action joins (paper: 500, 600 → 823,701 parameters)."""
    buffer_size: int = 100_000
    """Replay capacity per agent (Table A2)."""
    batch_size: int = 1000
    """Minibatch n (Table A2)."""
    policy_delay: int = 4
    """TD3/ATD3 delay d: actor and target updates every d critic updates (Table A4).
    Ignored (taken as 1) for ddpg / addpg."""
    learning_starts: int = 0
    """Transitions in the buffer before the first update; 0 means the batch size."""
    precision: Literal["fp32", "bf16"] = "fp32"
    """Compute precision of the learner's hidden layers (``networks.PRECISIONS``): fp32, or
    bf16 matmul inputs and activations with fp32 parameters, gradients, Adam state and
    GEMM accumulation (issue 17's mixed-precision option). Acting (data collection,
    evaluation, export) is always fp32. 16 paired seeds of ATD3+AfDP and of DDPG at
    ``stable`` learn the same in bf16 (results/precision_study.md); fp32 stays the default
    because every recorded result was trained in fp32 and bf16 is checked only there."""
    baseline: BaselineConfig | None = None
    """A Table 1 baseline (LfD, MCP+MF): prior-knowledge phases before the RL learner ``algo``
    (ddpg or td3, no advisor switches); None for the paper's agents."""

    def __post_init__(self):
        if self.baseline is not None:
            if not isinstance(self.baseline, BaselineConfig):
                raise ValueError(f"baseline must be a BaselineConfig, got {self.baseline!r}")
            check_baseline_learner(self.algo, self.advisor_data, self.advisor_policy)
        if self.algo not in ALGOS:
            raise ValueError(f"unknown algo {self.algo!r}; choose one of {', '.join(ALGOS)}")
        if self.advisor_policy and self.algo in ("ddpg", "td3"):
            raise ValueError(
                f"advisor_policy (AfP) needs the Eq. 2 actor target of addpg/atd3, "
                f"not algo={self.algo!r}"
            )
        if self.precision not in PRECISION_NAMES:
            raise ValueError(
                f"unknown precision {self.precision!r}; choose one of {', '.join(PRECISION_NAMES)}"
            )
        _positive("batch_size", self.batch_size)
        _positive("buffer_size", self.buffer_size)
        _positive("policy_delay", self.policy_delay)
        _positive("critic_state_hidden", self.critic_state_hidden)
        for name in ("actor_hidden", "critic_hidden"):
            widths = getattr(self, name)
            if not widths or any(int(w) <= 0 for w in widths):
                raise ValueError(f"{name} must be non-empty positive widths, got {widths}")
        if self.batch_size > self.buffer_size:
            raise ValueError(
                f"batch_size={self.batch_size} is larger than buffer_size={self.buffer_size}"
            )
        if self.learning_starts < 0 or self.learning_starts > self.buffer_size:
            raise ValueError(f"learning_starts={self.learning_starts} must be in [0, buffer_size]")

    @property
    def twin(self) -> bool:
        """Twin critics and target smoothing (TD3 family)."""
        return self.algo in ("td3", "atd3")

    @property
    def n_critics(self) -> int:
        return 2 if self.twin else 1

    @property
    def advisor_target(self) -> bool:
        """Actor trained towards Â of Eq. 2 (ADDPG family) rather than by the DPG."""
        return self.algo in ("addpg", "atd3")

    @property
    def delay(self) -> int:
        """Effective d: 1 for the DDPG family."""
        return self.policy_delay if self.twin else 1

    @property
    def warmup(self) -> int:
        return self.learning_starts or self.batch_size

    @property
    def name(self) -> str:
        """Paper-style name, e.g. ``ATD3+AfDP``; a baseline's is its own (``LfD``)."""
        if self.baseline is not None:
            return self.baseline.name
        suffix = {
            (True, True): "+AfDP",
            (True, False): "+AfD",
            (False, True): "+AfP",
            (False, False): "",
        }
        return self.algo.upper() + suffix[(self.advisor_data, self.advisor_policy)]


def parse_agent(name: str, **overrides) -> AgentConfig:
    """``"ATD3+AfDP"``, ``"LfD"`` or ``"MCP+MF"`` (any case) → AgentConfig. Extra keyword
    args override fields. A baseline name is recognised before the split on ``+``
    (docs/baselines.md); its learner is DDPG unless ``algo`` is overridden
    (``--baseline learner=td3``)."""
    plain = name.strip().lower().replace(" ", "")
    if plain in BASELINE_AGENTS:
        overrides = {"algo": "ddpg", "advisor_data": False, "advisor_policy": False, **overrides}
        overrides.setdefault("baseline", BaselineConfig(kind=BASELINE_AGENTS[plain]))
        return AgentConfig(**overrides)
    if overrides.get("baseline") is not None:
        raise ValueError(
            f"agent {name!r} is not a baseline; a baseline config needs "
            f"{' or '.join(map(repr, BASELINE_NAMES.values()))}"
        )
    parts = plain.split("+")
    algo, flags = parts[0], parts[1:]
    if algo in BASELINE_AGENTS:
        raise ValueError(
            f"unknown agent {name!r}: a baseline takes no advisor switches; use "
            f"{BASELINE_NAMES[BASELINE_AGENTS[algo]]!r}"
        )
    if algo not in ALGOS:
        raise ValueError(
            f"unknown agent {name!r}: the algorithm must be one of {', '.join(ALGOS)} "
            f"(optionally +AfD, +AfP or +AfDP), e.g. 'ATD3+AfDP', or a baseline: "
            f"{', '.join(BASELINE_NAMES.values())}"
        )
    known = {"afd": (True, False), "afp": (False, True), "afdp": (True, True)}
    data = policy = False
    for flag in flags:
        if flag not in known:
            raise ValueError(
                f"unknown advisor switch {flag!r} in agent {name!r}; use AfD, AfP or AfDP"
            )
        d, p = known[flag]
        data, policy = data or d, policy or p
    return AgentConfig(algo=algo, advisor_data=data, advisor_policy=policy, **overrides)


# The agent rows of the paper's Table 1 that this project implements.
PAPER_AGENTS = ("DDPG", "ADDPG", "ADDPG+AfD", "ADDPG+AfP", "ADDPG+AfDP", "ATD3+AfDP")


@struct.dataclass
class HParams:
    """Scalar hyperparameters; every field can differ across the agents of one vmap."""

    gamma: float = 0.9  # γ, Table A2
    tau: float = 0.1  # τ, soft target update, Eqs. (6), (7)
    beta: float = 0.01  # β, Eq. (2)
    lr_actor: float = 1e-5  # α_actor
    lr_critic: float = 1e-3  # α_critic
    eps_start: float = 0.85  # ε_st, Eq. (1)
    eps_decay: float = 0.0015  # b, Eq. (1): per episode (paper's 0.15 read per 100)
    advisor_episodes: float = 250.0  # N_T, Eq. (1): advisor off once N > N_T
    advisor_policy_episodes: float = 1e9  # N_P (ours): AfP replacement only while N <= N_P;
    # the paper replaces for the whole run, which the default (never reached) keeps
    ou_theta: float = 0.15  # Ornstein–Uhlenbeck mean reversion
    ou_sigma: float = 0.1  # Ornstein–Uhlenbeck scale (normalised action units)
    target_noise: float = 0.1  # σ̄, TD3 target smoothing (Table A4)
    target_noise_clip: float = 0.2  # c, Table A4
    beta_normalize: float = 0.0  # 0: Eq. (2)'s step is β∇_aQ (paper); 1: scale-free, β/rms‖∇_aQ‖
    clip_actor_target: float = 0.0  # 0: Â as printed (paper); 1: Â clipped to the action box
    clip_q_target: float = 0.0  # 0: Q̂ as printed (paper); 1: Q̂ clipped to the arena's return
    # bounds (envs.reward.return_bounds), against the single critic's overestimation runaway
    demo_episodes: float = 250.0  # D (LfD only): demonstration episodes, counted in N_total
    bc_lr: float = 1e-3  # imitation learning rate (LfD, MCP+MF; mbmf.py's 1e-3)
    random_episodes: float = 50.0  # R (MCP+MF only): uniform-action episodes, in N_total
    mpc_episodes: float = 40.0  # M (MCP+MF only): MPC episodes per round, in N_total
    dagger_episodes: float = 10.0  # MCP+MF only: actor episodes per DAgger round, in N_total
    model_lr: float = 1e-3  # MCP+MF only: the dynamics model's Adam learning rate
    model_noise: float = 0.01  # MCP+MF only: input noise σ of the model fit (normalised units)


HPARAM_NAMES: tuple[str, ...] = tuple(f.name for f in dataclasses.fields(HParams))

# Allowed ranges: (low, high, low inclusive, high inclusive).
_HPARAM_RANGES = {
    "gamma": (0.0, 1.0, True, False),
    "tau": (0.0, 1.0, False, True),
    "beta": (0.0, math.inf, True, False),
    "lr_actor": (0.0, math.inf, False, False),
    "lr_critic": (0.0, math.inf, False, False),
    "eps_start": (0.0, 1.0, True, True),
    "eps_decay": (0.0, math.inf, True, False),
    "advisor_episodes": (0.0, math.inf, True, False),
    "advisor_policy_episodes": (0.0, math.inf, True, False),
    "ou_theta": (0.0, math.inf, True, False),
    "ou_sigma": (0.0, math.inf, True, False),
    "target_noise": (0.0, math.inf, True, False),
    "target_noise_clip": (0.0, math.inf, True, False),
    "beta_normalize": (0.0, 1.0, True, True),
    "clip_actor_target": (0.0, 1.0, True, True),
    "clip_q_target": (0.0, 1.0, True, True),
    "demo_episodes": (1.0, math.inf, True, False),
    "bc_lr": (0.0, math.inf, False, False),
    "random_episodes": (1.0, math.inf, True, False),
    "mpc_episodes": (1.0, math.inf, True, False),
    "dagger_episodes": (1.0, math.inf, True, False),
    "model_lr": (0.0, math.inf, False, False),
    "model_noise": (0.0, math.inf, True, False),
}
# Switches: traced like every hyperparameter (one sweep can hold both settings), 0 or 1 only.
SWITCHES: tuple[str, ...] = ("beta_normalize", "clip_actor_target", "clip_q_target")


def validate_hparams(hp: HParams) -> None:
    """Raises ValueError naming the field, the bad value and the agent index (if stacked)."""
    for name in HPARAM_NAMES:
        values = np.atleast_1d(np.asarray(getattr(hp, name), dtype=np.float64))
        low, high, low_inc, high_inc = _HPARAM_RANGES[name]
        ok = np.isfinite(values) | (np.isinf(values) & (high == math.inf) & (values > 0))
        ok &= (values >= low) if low_inc else (values > low)
        ok &= (values <= high) if high_inc else (values < high)
        if name in SWITCHES:
            ok &= (values == 0.0) | (values == 1.0)
        if not ok.all():
            bad = int(np.flatnonzero(~ok)[0])
            where = f" (agent {bad})" if values.size > 1 else ""
            lo, hi = ("[" if low_inc else "("), ("]" if high_inc else ")")
            allowed = (
                "is a switch: 0 or 1"
                if name in SWITCHES
                else f"is outside {lo}{low:g}, {high:g}{hi}"
            )
            raise ValueError(f"hyperparameter {name}={values[bad]:g}{where} {allowed}")


@dataclasses.dataclass(frozen=True)
class TrainConfig:
    """Static description of a training run (shared by every agent of one vmap)."""

    agent: AgentConfig = AgentConfig()
    arena: str = "training"
    """Arena to train in (see ``advisor-jax arena --help``)."""
    episodes: int = 500
    """N_total: training episodes per agent."""
    envs_per_agent: int = 1
    """Environments each agent collects from in parallel (paper: 1)."""
    updates_per_step: int = 1
    """Gradient updates per environment step of an agent (the paper trains
    asynchronously; we update synchronously)."""
    chunk_steps: int = 1000
    """Environment steps per jitted host-loop iteration (progress, metrics, checkpoints)."""
    max_episode_steps: int = 0
    """h_max; 0 means the arena's default (300 simulation, 150 physical)."""
    motion: str = "kinematic"
    """Motion model of every arena (training and evaluation): kinematic (a unicycle,
    (V, ω) take effect at once) or mjx (the P3DX's body and wheels stepped by MJX, with
    acceleration, turn and speed limits), optionally with parameters, e.g.
    mjx:wheel_torque_max=0.5 (envs/motion.py, docs/arena_calibration.md)."""
    snapshot_episodes: tuple[int, ...] = ()
    """Also keep each agent's actor as it was on completing this many episodes (each < N_total)
    and evaluate it beside the final one: nothing before episode N depends on N_total, so
    it is the actor a run of N episodes ends with, and one 500-episode run also answers
    for 200 (the paper's sample-efficiency question)."""

    def __post_init__(self):
        _positive("episodes", self.episodes)
        model = str(self.motion).partition(":")[0]  # parameters: checked by envs.make_env
        if model not in spec.MOTION_MODELS:
            raise ValueError(
                f"motion={self.motion!r}: unknown motion model {model!r}; choose one of "
                f"{', '.join(spec.MOTION_MODELS)}"
            )
        snaps = self.snapshot_episodes
        if list(snaps) != sorted(set(snaps)) or any(not 0 < n < self.episodes for n in snaps):
            raise ValueError(
                f"snapshot_episodes must be distinct, increasing and between 1 and "
                f"episodes - 1 = {self.episodes - 1}, got {list(snaps)}"
            )
        _positive("envs_per_agent", self.envs_per_agent)
        _positive("updates_per_step", self.updates_per_step)
        _positive("chunk_steps", self.chunk_steps)
        if self.max_episode_steps < 0:
            raise ValueError(f"max_episode_steps must be >= 0, got {self.max_episode_steps}")
        if self.agent.baseline is not None and self.envs_per_agent != 1:
            raise ValueError(
                f"envs_per_agent={self.envs_per_agent} with the {self.agent.name} baseline: "
                "its phase boundaries are episode counts, so it needs envs_per_agent=1"
            )


# Presets --------------------------------------------------------------------------------

# paper, physical and quick keep the paper's literal Eqs. (2) and (4) (beta_normalize = 0,
# clip_actor_target = 0, clip_q_target = 0). stable is paper with the readings that 16 seeds
# per agent type support (docs/architecture.md R33-R35):
# - Â clipped to the action box and a scale-free step of length β = 1
#   (results/afp_collapse/afp_collapse.md): at literal β >= 3, 4 of 8 ATD3+AfDP seeds
#   collapsed (saturated heads, steps of 5-164 action units); scale-free and clipped, none
#   of 24 did, and the mean rose from the paper's β's ~60 % to 82 %;
# - the TD target clipped to the arena's return bounds (results/q_target_clip.md): without
#   it 7 of 64 ADDPG-family seeds collapsed as their one critic overestimated past any
#   achievable return; with it none of 80 seeds of five agent types ended below 56 %.
PRESETS: dict[str, tuple[dict, dict, dict]] = {
    # name: (AgentConfig overrides, TrainConfig overrides, HParams overrides)
    "paper": ({}, {}, {}),
    "stable": (
        {}, {}, dict(beta=1.0, beta_normalize=1.0, clip_actor_target=1.0, clip_q_target=1.0)
    ),
    "physical": (
        dict(buffer_size=50_000, batch_size=500, policy_delay=3),
        dict(arena="physical", episodes=200),
        dict(lr_actor=1e-4, eps_start=0.9, eps_decay=0.001, advisor_episodes=100.0,
             target_noise=0.05, target_noise_clip=0.1, demo_episodes=100.0,
             random_episodes=20.0, mpc_episodes=16.0, dagger_episodes=4.0),
    ),
    # Small networks and budgets that train in minutes on a 2-core CPU.
    "quick": (
        dict(actor_hidden=(64, 64), critic_state_hidden=128, critic_hidden=(128, 128),
             buffer_size=20_000, batch_size=128),
        dict(episodes=60, chunk_steps=500),
        dict(lr_actor=1e-3, advisor_episodes=30.0, eps_decay=0.01, demo_episodes=30.0,
             random_episodes=6.0, mpc_episodes=8.0, dagger_episodes=4.0),
    ),
}  # fmt: skip
# The baselines' static settings per preset (BaselineConfig overrides) are in
# ``baselines.BASELINE_PRESETS``; their HParams (demo_episodes = N_T; MCP+MF's random, MPC
# and DAgger episodes summing to N_T) are above.


def preset(
    name: str, agent: str = "ATD3+AfDP", baseline: dict | None = None, **agent_overrides
) -> tuple[TrainConfig, HParams]:
    """A named preset for one agent type: (static config, hyperparameters).

    ``agent_overrides`` replace AgentConfig fields of the preset (e.g. ``batch_size=64``);
    ``baseline`` replaces BaselineConfig fields of a baseline agent (``learner`` sets its
    ``algo``), as parsed by ``baselines.parse_baseline_settings``.
    """
    if name not in PRESETS:
        raise ValueError(f"unknown preset {name!r}; choose one of {', '.join(PRESETS)}")
    agent_kw, train_kw, hp_kw = PRESETS[name]
    agent_cfg = parse_agent(agent, **{**agent_kw, **agent_overrides})
    if agent_cfg.baseline is not None:
        kind = agent_cfg.baseline.kind
        defaults = {k: v for k, v in BASELINE_PRESETS[name].items() if k in BASELINE_KEYS[kind]}
        settings = {**defaults, **(baseline or {})}
        algo = settings.pop("learner", agent_cfg.algo)
        agent_cfg = dataclasses.replace(
            agent_cfg, algo=algo, baseline=dataclasses.replace(agent_cfg.baseline, **settings)
        )
    elif baseline:
        raise ValueError(
            f"unknown baseline setting {', '.join(map(repr, baseline))}: agent {agent!r} is "
            "not a baseline"
        )
    return TrainConfig(agent=agent_cfg, **train_kw), HParams(**hp_kw)


def train_config_from_dict(d: dict) -> TrainConfig:
    """Inverse of ``dataclasses.asdict(TrainConfig)`` (as saved in run.json)."""
    try:
        agent = dict(d["agent"])
        for name in ("actor_hidden", "critic_hidden"):
            agent[name] = tuple(agent[name])
        d = {**d, "snapshot_episodes": tuple(d.get("snapshot_episodes", ()))}
        if agent.get("baseline") is not None:
            agent["baseline"] = BaselineConfig(**agent["baseline"])
        return TrainConfig(**{**d, "agent": AgentConfig(**agent)})
    except (KeyError, TypeError) as e:
        raise ValueError(f"not a training configuration: {e}") from None
