"""``advisor-jax train --agent brax-SAC|brax-PPO``: the options checked, before any compile.

The preset gives the budget and the arenas as for every other agent type (N_total, the
training arena, h_max, γ, the evaluation arenas); ``--baseline KEY=VALUE`` changes a brax
setting (``agent.brax_agents``). Options that configure advisor-jax's own learner (``--hp``,
``--grid``, ``--batch-size``, ...) are refused, naming the option and what to use instead.
"""

from __future__ import annotations

import dataclasses
from pathlib import Path

from advisor_jax.agent.brax_agents import (
    BRAX_SEED_MAX,
    PpoSettings,
    SacSettings,
    brax_agent_name,
    default_settings,
    parse_settings,
)
from advisor_jax.agent.config import PRESETS, preset
from advisor_jax.training.limits import check_agents, check_episodes, check_eval_episodes

# TrainArgs options that mean something for a brax agent; every other one must keep its
# default (``_refuse_others``).
BRAX_OPTIONS = frozenset({
    "preset", "agent", "seeds", "seed", "baseline", "episodes", "arena", "max_episode_steps",
    "out", "eval_episodes", "eval_arenas", "eval_seed", "resume", "no_progress",
    "tensorboard", "wandb", "motion",
})  # fmt: skip


@dataclasses.dataclass(frozen=True)
class BraxRequest:
    """A checked ``advisor-jax train --agent brax-...`` call (``request.build_brax_run``)."""

    agent: str  # brax-SAC or brax-PPO
    settings: SacSettings | PpoSettings
    preset: str
    arena: str
    episodes: int  # N_total per agent
    max_episode_steps: int  # h_max (0: the arena's)
    motion: str  # the robot's motion model (envs.motion), canonical setting
    seeds: tuple[int, ...]
    out: Path
    eval_episodes: int
    eval_arenas: tuple[str, ...]
    eval_seed: int
    resume: bool = False


def build_brax_run(args, default_out) -> BraxRequest:
    """The checked request of a ``TrainArgs`` whose ``--agent`` is a brax agent;
    ``default_out(agent, preset)`` names the run directory when ``--out`` is left out."""
    import envs

    agent = brax_agent_name(args.agent)
    if agent is None:
        raise ValueError(f"{args.agent!r} is not a brax agent (brax-SAC or brax-PPO)")
    _refuse_others(args, agent)
    if args.preset not in PRESETS:
        raise ValueError(f"unknown preset {args.preset!r}; choose one of {', '.join(PRESETS)}")
    if args.seeds <= 0:
        raise ValueError(f"--seeds must be a positive integer, got {args.seeds}")
    check_agents(args.seeds)
    last = args.seed + args.seeds - 1
    if args.seed < 0 or last > BRAX_SEED_MAX:
        raise ValueError(
            f"--seed {args.seed} --seeds {args.seeds}: brax agents take seeds 0 .. "
            f"{BRAX_SEED_MAX} (brax keys its run with jax.random.PRNGKey(seed))"
        )
    cfg, _ = preset(args.preset, "DDPG")  # the preset's budget, arena and h_max
    episodes = args.episodes if args.episodes is not None else cfg.episodes
    check_episodes(episodes)
    arena = args.arena or cfg.arena
    h_max = args.max_episode_steps if args.max_episode_steps is not None else cfg.max_episode_steps
    if h_max < 0:
        raise ValueError(f"--max-episode-steps must be >= 0 (0: the arena's), got {h_max}")
    arenas = tuple(args.eval_arenas or (("physical",) if arena == "physical" else
                                        ("training", "validation")))  # fmt: skip
    for name in (arena, *arenas):
        if name not in envs.ARENAS:
            raise ValueError(f"unknown arena {name!r}; choose from {', '.join(envs.ARENAS)}")
    if len(set(arenas)) != len(arenas):
        raise ValueError(f"an evaluation arena is named twice: {', '.join(arenas)}")
    if args.eval_episodes:
        check_eval_episodes(args.eval_episodes, args.seeds)
    elif args.eval_episodes < 0:
        raise ValueError(f"--eval-episodes must be >= 0, got {args.eval_episodes}")
    motion = envs.EnvConfig(**envs.parse_motion(args.motion or cfg.motion)).motion_setting
    settings = parse_settings(agent, default_settings(agent, args.preset), args.baseline)
    out = Path(args.out) if args.out is not None else default_out(agent, args.preset)
    return BraxRequest(
        agent=agent,
        settings=settings,
        preset=args.preset,
        arena=arena,
        episodes=episodes,
        max_episode_steps=h_max,
        motion=motion,
        seeds=tuple(range(args.seed, args.seed + args.seeds)),
        out=out,
        eval_episodes=args.eval_episodes,
        eval_arenas=arenas,
        eval_seed=args.seed if args.eval_seed is None else args.eval_seed,
        resume=args.resume,
    )


def _refuse_others(args, agent: str) -> None:
    """ValueError naming the first option that has no meaning for a brax agent."""
    for field in dataclasses.fields(args):
        if field.name in BRAX_OPTIONS:
            continue
        if getattr(args, field.name) != field.default:
            option = "--" + field.name.replace("_", "-")
            raise ValueError(
                f"{option} does not apply to {agent}: brax trains its own networks (change "
                "its settings with --baseline KEY=VALUE, docs/baselines.md)"
            )
