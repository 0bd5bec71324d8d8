"""What sets one agent's point apart: its settings from run.json, and how they differ from a
preset's (``runs.pool`` groups seeds by them; reports label points with the differences)."""

from __future__ import annotations

import dataclasses
import math

from advisor_jax.agent.baselines import BASELINE_AGENTS, unread_hparams
from advisor_jax.agent.brax_agents import brax_agent_name, default_settings
from advisor_jax.agent.config import HPARAM_NAMES, AgentConfig, TrainConfig, preset
from advisor_jax.agent.hparams import HPARAM_DEFAULTS
from advisor_jax.agent.settings import flat_items

AGENT_FIELDS = (
    "algo",
    "actor_hidden",
    "critic_state_hidden",
    "critic_hidden",
    "buffer_size",
    "batch_size",
    "policy_delay",
    "learning_starts",
    "precision",
    "baseline",
)
TRAIN_FIELDS = ("arena", "envs_per_agent", "updates_per_step", "max_episode_steps", "motion",
                "advisor")  # fmt: skip


def canonical(value):
    """A setting as a hashable, comparable value (floats to 9 significant digits)."""
    if isinstance(value, list):
        return tuple(canonical(v) for v in value)
    if isinstance(value, dict):
        return tuple(sorted((k, canonical(v)) for k, v in value.items()))
    if isinstance(value, float):
        return float(f"{value:.9g}")
    return value


def settings_of(summary: dict, row: dict) -> dict:
    """Everything that changes what one agent learns: every hyperparameter (a field an older
    run.json lacks: ``HParams``'s default, what that run trained with) and static setting;
    for a brax agent, its brax settings (``gamma`` = its discounting), arena and h_max."""
    config = summary["config"]
    if summary.get("kind") == "brax":
        brax = {k: canonical(v) for k, v in config["brax"].items()}
        return {**brax, "gamma": brax["discounting"], **_brax_task(config)}
    agent_defaults, train_defaults = AgentConfig(), TrainConfig()
    out = {n: canonical(float(row.get(n, HPARAM_DEFAULTS[n]))) for n in HPARAM_NAMES}
    for field in AGENT_FIELDS:
        out[field] = canonical(config["agent"].get(field, getattr(agent_defaults, field)))
    for field in TRAIN_FIELDS:
        out[field] = canonical(config.get(field, getattr(train_defaults, field)))
    return out


def _brax_task(config: dict) -> dict:
    return {
        "arena": config.get("arena", "training"),
        "max_episode_steps": config.get("max_episode_steps", 0),
        "motion": config.get("motion", "kinematic"),
    }


def _brax_differences(preset_name: str, agent: str, settings: dict) -> dict:
    static, _ = preset(preset_name, "DDPG")
    brax = default_settings(agent, preset_name)
    default = {k: canonical(v) for k, v in dataclasses.asdict(brax).items()}
    default |= {"gamma": default["discounting"], **_brax_task(dataclasses.asdict(static))}
    return {k: v for k, v in settings.items() if default.get(k) != v}


def preset_differences(preset_name: str, agent: str, settings: dict) -> dict:
    """The settings in which an agent differs from ``preset_name``'s for its type (those it
    does not read left out)."""
    if brax_agent_name(agent) is not None:
        return _brax_differences(preset_name, agent, settings)
    static, hp = preset(preset_name, agent)
    hp_values = {**HPARAM_DEFAULTS, **flat_items(hp)}
    unread = unread_hparams(BASELINE_AGENTS.get(agent.lower()))  # set per point, change nothing
    out = {}
    for name, value in settings.items():
        if name in unread:
            continue
        if name in HPARAM_NAMES:
            default = float(hp_values[name])
        elif name in AGENT_FIELDS:
            default = canonical(dataclasses.asdict(static.agent)[name])
        else:
            default = canonical(getattr(static, name))
        same = (
            math.isclose(value, default, rel_tol=1e-6)
            if isinstance(value, float)
            else value == default
        )
        if not same:
            out[name] = value
    return out
