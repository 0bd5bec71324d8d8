"""brax's SAC and PPO as baseline agent types: their settings and a trained one's policy.

``--agent brax-SAC`` and ``--agent brax-PPO`` train with brax's own trainers
(``brax.training.agents.{sac,ppo}.train``) on ``envs.make_brax_env`` (the same arenas);
``training/brax_baselines/`` runs them under the paper's episode budget and writes the usual
run directory. Each setting is declared once here, with its value and why
(docs/baselines.md, "brax SAC and PPO"); ``--baseline KEY=VALUE`` changes one. ``policy_apply``
is the deterministic policy of a trained agent (the mode of brax's tanh-Gaussian, as brax's
own deterministic evaluation uses) in the arena's action box, for our evaluator.

Stored parameters (params/ of a run, every agent on a leading axis)::

    obs_mean, obs_std [agents, 20]   brax's observation normaliser (0 and 1 when it is off)
    policy                           brax's policy network (flax params)
"""

from __future__ import annotations

import dataclasses
import functools
import typing
from collections.abc import Callable, Sequence
from typing import Any

import jax
import jax.numpy as jnp

from advisor_jax.contract import spec

BRAX_AGENTS = {"brax-sac": "brax-SAC", "brax-ppo": "brax-PPO"}  # typed name (lowercase) -> name
BRAX_SEED_MAX = 2**31 - 1  # brax keys its run with jax.random.PRNGKey(seed)


def brax_agent_name(agent: str) -> str | None:
    """``brax-SAC`` / ``brax-PPO`` for any spelling (``brax-sac``, ``Brax-PPO``), else None."""
    return BRAX_AGENTS.get(agent.strip().lower().replace(" ", "").replace("_", "-"))


@dataclasses.dataclass(frozen=True)
class SacSettings:
    """brax SAC (Haarnoja et al. 2018) as ``brax.training.agents.sac.train`` takes it."""

    hidden: tuple[int, ...] = (256, 256)
    """Hidden widths of the policy and of each Q network (brax's default)."""
    learning_rate: float = 3e-4
    """Adam learning rate of policy and Q networks (SAC's published value)."""
    discounting: float = 0.9
    """γ: the preset's (the paper's 0.9, Table A2), so the return is the same task's."""
    tau: float = 0.005
    """Soft target update rate (SAC's published value)."""
    batch_size: int = 256
    """Minibatch per gradient update (SAC's published value)."""
    num_envs: int = 8
    """Parallel environments stepped per actor step."""
    grad_updates_per_step: int = 8
    """Gradient updates per actor step: with num_envs 8, one update per env step, the
    paper's (and our agents') ratio."""
    min_replay_size: int = 1000
    """Env steps of the initial policy before the first update (our agents' warm-up: one
    batch of the paper's 1,000)."""
    max_replay_size: int = 100_000
    """Replay capacity: the preset's buffer (the paper's 100,000, Table A2)."""
    reward_scaling: float = 1.0
    """Reward multiplier (Eq. 8 as is)."""
    normalize_observations: bool = True
    """brax's running mean/std of the observation (raw distances and angles differ in scale)."""


@dataclasses.dataclass(frozen=True)
class PpoSettings:
    """brax PPO (Schulman et al. 2017) as ``brax.training.agents.ppo.train`` takes it."""

    policy_hidden: tuple[int, ...] = (32, 32, 32, 32)
    """Policy network widths (brax's default)."""
    value_hidden: tuple[int, ...] = (256, 256, 256, 256, 256)
    """Value network widths (brax's default)."""
    learning_rate: float = 3e-4
    """Adam learning rate (PPO's published value)."""
    discounting: float = 0.9
    """γ: the paper's (Table A2)."""
    gae_lambda: float = 0.95
    """GAE λ (PPO's published value)."""
    entropy_cost: float = 1e-2
    """Entropy bonus weight."""
    clipping_epsilon: float = 0.2
    """PPO's ratio clip (published value)."""
    num_envs: int = 16
    """Parallel environments of a rollout."""
    unroll_length: int = 20
    """Steps per environment per rollout segment."""
    batch_size: int = 16
    """Segments per minibatch: 16 × 20 × 4 minibatches = 1,280 env steps per update."""
    num_minibatches: int = 4
    """Minibatches per update."""
    num_updates_per_batch: int = 4
    """Epochs over each batch of rollouts."""
    reward_scaling: float = 1.0
    """Reward multiplier (Eq. 8 as is)."""
    normalize_observations: bool = True
    """brax's running mean/std of the observation."""

    def __post_init__(self):
        if (self.batch_size * self.num_minibatches) % self.num_envs:
            raise ValueError(
                f"brax PPO needs batch_size × num_minibatches ({self.batch_size} × "
                f"{self.num_minibatches}) to be a multiple of num_envs ({self.num_envs})"
            )


SETTINGS = {"brax-SAC": SacSettings, "brax-PPO": PpoSettings}
QUICK = {  # the `quick` preset: CPU-sized networks and batches (tests, smoke runs)
    "brax-SAC": dict(hidden=(64, 64), batch_size=64, min_replay_size=256),
    "brax-PPO": dict(policy_hidden=(32, 32), value_hidden=(64, 64), unroll_length=10),
}


def default_settings(agent: str, preset_name: str) -> SacSettings | PpoSettings:
    """The settings of ``agent`` at a preset: its γ (and for SAC its replay capacity), and
    CPU-sized networks at ``quick``."""
    from advisor_jax.agent.config import preset

    cfg, hp = preset(preset_name, "DDPG")
    task = {"discounting": float(hp.gamma)}
    if agent == "brax-SAC":
        task["max_replay_size"] = cfg.agent.buffer_size
    overrides = QUICK[agent] if preset_name == "quick" else {}
    return SETTINGS[agent](**task, **overrides)


def parse_settings(agent: str, base, items: Sequence[str]):
    """``base`` with ``--baseline KEY=VALUE`` items applied; ValueError naming the item."""
    cls = type(base)
    types = typing.get_type_hints(cls)
    changes: dict[str, Any] = {}
    for item in items:
        key, sep, text = (part.strip() for part in item.partition("="))
        if not sep or not text:
            raise ValueError(f"--baseline expects KEY=VALUE, got {item!r}")
        if key not in types:
            raise ValueError(f"unknown setting {key!r} for {agent}; choose from {', '.join(types)}")
        if key in changes:
            raise ValueError(f"--baseline sets {key} twice; give it once")
        changes[key] = _parse_value(key, text, types[key])
    try:
        return dataclasses.replace(base, **changes)
    except ValueError as e:
        raise ValueError(f"--baseline: {e}") from None


def _parse_value(key: str, text: str, kind) -> Any:
    """A ``--baseline`` value as its field's type: int, float, bool or integer widths."""
    try:
        if kind is bool:
            if text.lower() not in ("0", "1", "true", "false"):
                raise ValueError
            return text.lower() in ("1", "true")
        if kind == tuple[int, ...]:
            widths = tuple(int(w) for w in text.split(","))
            if not widths or min(widths) <= 0:
                raise ValueError
            return widths
        value = kind(text)
    except ValueError:
        expected = {bool: "0 or 1", tuple[int, ...]: "positive integer widths, e.g. 256,256"}
        raise ValueError(
            f"--baseline {key}={text!r}: expected {expected.get(kind, kind.__name__)}"
        ) from None
    if value <= 0 and key not in ("entropy_cost",):
        raise ValueError(f"--baseline {key}={text!r}: must be positive")
    return value


def network_factory(settings: SacSettings | PpoSettings) -> Callable:
    """brax's ``network_factory`` argument for these settings (brax's trainer adds the
    observation normaliser)."""
    from brax.training.agents.ppo import networks as ppo_networks
    from brax.training.agents.sac import networks as sac_networks

    if isinstance(settings, SacSettings):
        return functools.partial(sac_networks.make_sac_networks, hidden_layer_sizes=settings.hidden)
    return functools.partial(
        ppo_networks.make_ppo_networks,
        policy_hidden_layer_sizes=settings.policy_hidden,
        value_hidden_layer_sizes=settings.value_hidden,
    )


def policy_apply(settings: SacSettings | PpoSettings) -> Callable[[dict, jax.Array], jax.Array]:
    """``apply(params, obs [..., 20]) -> action [..., 2]`` in the arena's box: the mode of the
    trained policy (brax's ``deterministic=True``) mapped by ``envs.brax_env.to_nav_action``."""
    from brax.training import types as brax_types
    from brax.training.acme import running_statistics
    from brax.training.agents.ppo import networks as ppo_networks
    from brax.training.agents.sac import networks as sac_networks

    from envs.brax_env import to_nav_action

    normalize = (
        running_statistics.normalize
        if settings.normalize_observations
        else brax_types.identity_observation_preprocessor
    )
    factory = network_factory(settings)
    if isinstance(settings, SacSettings):  # each trainer's own way of naming the size
        networks = factory(spec.OBS_SIZE, spec.ACTION_SIZE, preprocess_observations_fn=normalize)
        make_policy = sac_networks.make_inference_fn(networks)
    else:
        networks = factory((spec.OBS_SIZE,), spec.ACTION_SIZE, preprocess_observations_fn=normalize)
        make_policy = ppo_networks.make_inference_fn(networks)

    def apply(params: dict, obs: jax.Array) -> jax.Array:
        normalizer = running_statistics.NestedMeanStd(
            mean=params["obs_mean"], std=params["obs_std"]
        )
        policy = make_policy((normalizer, params["policy"]), deterministic=True)
        action, _ = policy(obs, jax.random.PRNGKey(0))  # deterministic: the key is unused
        return to_nav_action(action)

    return apply


def stored_params(brax_params: tuple) -> dict:
    """brax's returned params ``(normalizer, policy, ...)`` as params/ stores one agent's."""
    normalizer, policy = brax_params[0], brax_params[1]
    return {
        "obs_mean": jnp.asarray(normalizer.mean, jnp.float32),
        "obs_std": jnp.asarray(normalizer.std, jnp.float32),
        "policy": policy,
    }


def settings_from_dict(agent: str, values: dict) -> SacSettings | PpoSettings:
    """The settings run.json recorded (lists back to tuples)."""
    cls = SETTINGS[agent]
    fields = {f.name for f in dataclasses.fields(cls)}
    unknown = sorted(set(values) - fields)
    if unknown:
        raise ValueError(f"unknown {agent} setting(s) {', '.join(unknown)}")
    return cls(**{k: tuple(v) if isinstance(v, list) else v for k, v in values.items()})
