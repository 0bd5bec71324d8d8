"""Configuration: the static settings of an agent type and a run, and the presets.

Two kinds of configuration (docs/architecture.md, "Configuration"; ``settings``):

* ``AgentConfig`` / ``TrainConfig`` are frozen dataclasses of *static* values: anything that
  fixes a shape, a loop length or a code path (network sizes, buffer and batch sizes, the
  algorithm and advisor switches, the TD3 delay d). Changing one recompiles.
* The hyperparameters (``hparams.HParams``, a baseline's own) are scalars, pytree leaves:
  a grid of seeds × hyperparameters is one ``vmap`` and one compile.

Every setting is declared once, with its value in each preset where that differs from the
default (``settings.setting`` / ``settings.hparam``); ``PRESETS`` names and explains the
presets, ``preset`` builds one agent type's configuration and hyperparameters from them.
"""

from __future__ import annotations

import dataclasses
from collections.abc import Mapping
from typing import Literal

from advisor_jax.agent.baselines import (
    BASELINE_AGENTS,
    BASELINE_KEYS,
    BASELINE_NAMES,
    BaselineConfig,
    check_baseline_learner,
)
from advisor_jax.agent.hparams import (
    HPARAM_NAMES,
    PRIOR_HPARAMS,
    SWITCHES,
    BaselineHParams,
    HParams,
)
from advisor_jax.agent.settings import (
    PRESET_NAMES,
    flat_fields,
    preset_values,
    replace_flat,
    setting,
)
from advisor_jax.agent.settings import freeze as freeze
from advisor_jax.agent.settings import validate as validate_hparams
from advisor_jax.contract import spec

__all__ = ["HPARAM_NAMES", "SWITCHES", "HParams", "BaselineHParams", "freeze", "validate_hparams"]

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
    actor_hidden: tuple[int, ...] = setting((600, 300), presets={"quick": (64, 64)})
    """Actor hidden widths (paper: 600, 300 → 193,502 parameters)."""
    critic_state_hidden: int = setting(1000, presets={"quick": 128})
    """Critic width of the state-only first layer (paper: 1000)."""
    critic_hidden: tuple[int, ...] = setting((500, 600), presets={"quick": (128, 128)})
    """Critic widths after the action joins (paper: 500, 600 → 823,701 parameters)."""
    buffer_size: int = setting(100_000, presets={"physical": 50_000, "quick": 20_000})
    """Replay capacity per agent (Table A2)."""
    batch_size: int = setting(1000, presets={"physical": 500, "quick": 128})
    """Minibatch n (Table A2)."""
    policy_delay: int = setting(4, presets={"physical": 3})
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


@dataclasses.dataclass(frozen=True)
class TrainConfig:
    """Static description of a training run (shared by every agent of one vmap)."""

    agent: AgentConfig = AgentConfig()
    arena: str = setting("training", presets={"physical": "physical"})
    """Arena to train in (see ``advisor-jax arena --help``)."""
    episodes: int = setting(500, presets={"physical": 200, "quick": 60})
    """N_total: training episodes per agent."""
    envs_per_agent: int = 1
    """Environments each agent collects from in parallel (paper: 1)."""
    updates_per_step: int = 1
    """Gradient updates per environment step of an agent (the paper trains
    asynchronously; we update synchronously)."""
    chunk_steps: int = setting(1000, presets={"quick": 500})
    """Environment steps per jitted host-loop iteration (progress, metrics, checkpoints)."""
    max_episode_steps: int = 0
    """h_max; 0 means the arena's default (300 simulation, 150 physical)."""
    motion: str = "kinematic"
    """Motion model of every arena (training and evaluation): kinematic (a unicycle,
    (V, ω) take effect at once) or mjx (the P3DX's body and wheels stepped by MJX, with
    acceleration, turn and speed limits), optionally with parameters, e.g.
    mjx:wheel_torque_max=0.5 (envs/motion.py, docs/arena_calibration.md)."""
    advisor: str = "rule"
    """The advisor (docs/advisors.md): rule (the paper's Algorithm A1), a registered name,
    MODULE:FUNCTION, a training run RUN[:AGENT] or an export directory. Its quality knobs
    are hyperparameters (advisor_noise, advisor_random, ...)."""
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
        if not isinstance(self.advisor, str) or not self.advisor.strip():
            raise ValueError(
                f"advisor must name an advisor (docs/advisors.md), got {self.advisor!r}"
            )
        if self.agent.baseline is not None and self.envs_per_agent != 1:
            raise ValueError(
                f"envs_per_agent={self.envs_per_agent} with the {self.agent.name} baseline: "
                "its phase boundaries are episode counts, so it needs envs_per_agent=1"
            )


# Presets --------------------------------------------------------------------------------


@dataclasses.dataclass(frozen=True)
class Preset:
    """A named starting point: its values are declared at each setting (``presets=``)."""

    name: str
    help: str


PRESETS: dict[str, Preset] = {
    p.name: p
    for p in (
        Preset("quick", "small networks and budgets that train in minutes on a 2-core CPU"),
        Preset("paper", "Tables A2/A4, simulation column"),
        Preset(
            "stable",
            "paper with Eq. 2's Â clipped to the action box, a scale-free step β = 1 and the "
            "TD target clipped to the arena's return bounds: no seed of any Table 1 type below "
            "the advisor in 16 (docs/architecture.md R33-R35)",
        ),
        Preset("physical", "Tables A2/A4, physical column, physical arena"),
    )
}
assert tuple(sorted(PRESETS)) == tuple(sorted(PRESET_NAMES))


def default_hparams(agent: AgentConfig, preset_name: str = "paper") -> HParams | BaselineHParams:
    """The hyperparameters of ``agent``'s type in a preset: an ``HParams``, or for a baseline
    a ``BaselineHParams`` holding its prior phases' own too."""
    rl = HParams(**preset_values(HParams, preset_name))
    if agent.baseline is None:
        return rl
    prior = PRIOR_HPARAMS[agent.baseline.kind]
    return BaselineHParams(rl=rl, prior=prior(**preset_values(prior, preset_name)))


def preset(
    name: str, agent: str = "ATD3+AfDP", baseline: dict | None = None, **agent_overrides
) -> tuple[TrainConfig, HParams]:
    """A named preset for one agent type: (static config, hyperparameters).

    ``agent_overrides`` replace AgentConfig fields of the preset (e.g. ``batch_size=64``);
    ``baseline`` replaces BaselineConfig fields of a baseline agent (``learner`` sets its
    ``algo``), as parsed by ``baselines.parse_baseline_settings``. The hyperparameters are
    ``default_hparams``: an ``HParams``, or a baseline's ``BaselineHParams``.
    """
    if name not in PRESETS:
        raise ValueError(f"unknown preset {name!r}; choose one of {', '.join(PRESETS)}")
    agent_kw = preset_values(AgentConfig, name, changed_only=True)
    agent_cfg = parse_agent(agent, **{**agent_kw, **agent_overrides})
    if agent_cfg.baseline is not None:
        kind = agent_cfg.baseline.kind
        defaults = preset_values(BaselineConfig, name, changed_only=True)
        defaults = {k: v for k, v in defaults.items() if k in BASELINE_KEYS[kind]}
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
    train_kw = preset_values(TrainConfig, name, changed_only=True)
    return TrainConfig(agent=agent_cfg, **train_kw), default_hparams(agent_cfg, name)


def train_config_from_dict(d: dict) -> TrainConfig:
    """Inverse of ``dataclasses.asdict(TrainConfig)`` (as saved in run.json, by this version
    or an older one: settings added since take their defaults)."""
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


def hparams_from_row(agent: AgentConfig, row: Mapping[str, float]) -> HParams | BaselineHParams:
    """One agent's hyperparameters from its run.json ``agents`` row (flat names), for
    ``agent``'s type. Rows of older versions load too: a name the type does not declare is
    ignored (they listed every baseline's hyperparameters for every agent), one they lack
    takes the ``paper`` default (it was added since, with the default the run had)."""
    base = default_hparams(agent)
    names = flat_fields(base)
    return replace_flat(base, **{n: float(row[n]) for n in names if n in row})
