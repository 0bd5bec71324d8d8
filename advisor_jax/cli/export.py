"""``advisor-jax export``: one trained agent → policy directory for the numpy car runner."""

from __future__ import annotations

import dataclasses
from pathlib import Path
from typing import Annotated

import tyro

from advisor_jax.agent.config import HPARAM_NAMES
from advisor_jax.cli.helptext import flowing


@flowing
@dataclasses.dataclass(frozen=True)
class ExportArgs:
    """Export a trained actor (policy.npz, policy.json, golden.npz [, policy.onnx]).

    The golden set holds observations from real rollouts of the exported actor in its
    training arena plus edge cases, with the JAX actor's actions; the car runner refuses
    to drive unless its numpy MLP reproduces them within 1e-5.

    Example:
      advisor-jax export runs/atd3_afdp-quick-20261122 --agent 0 --out policy/ --onnx
    """

    source: Annotated[Path, tyro.conf.Positional]
    """Run directory written by ``advisor-jax train``."""
    out: Annotated[str, tyro.conf.arg(metavar="DIR")]
    """Export directory: created, complete or not at all; it must not exist yet or be empty
    (an export never writes over files)."""
    agent: int = 0
    """Index of the agent in the run (see run.json "agents")."""
    onnx: bool = False
    """Also write policy.onnx (opset 13), checked against onnxruntime."""
    golden_envs: int = 16
    """Parallel rollout environments for the golden observations."""
    golden_steps: int = 32
    """Rollout steps per environment for the golden observations."""
    seed: int = 0
    """Seed of the golden rollouts."""
    sign_key: Annotated[Path | None, tyro.conf.arg(metavar="KEYFILE")] = None
    """Sign the export with the key in this file (policy.sig, an HMAC-SHA256 of policy.json);
    a car started with --verify-key KEYFILE then refuses any export not signed with it. Make
    a key with: head -c 32 /dev/urandom > KEYFILE (keep it off the policy directory)."""


def export_command(args: ExportArgs) -> dict:
    """Entry point of ``advisor-jax export``; returns the written policy.json dict."""

    import envs
    from advisor_jax.agent.networks import make_actor
    from advisor_jax.deploy.export import check_new_export_dir, export_policy
    from advisor_jax.evaluation.evaluate import rollout_observations
    from advisor_jax.runner.signature import read_key
    from advisor_jax.training.limits import check_eval_episodes
    from advisor_jax.training.population import seed_key
    from advisor_jax.training.run_directory import load_actor, load_run

    if args.golden_envs <= 0 or args.golden_steps <= 0:
        raise ValueError("--golden-envs and --golden-steps must be positive")
    check_eval_episodes(args.golden_envs * args.golden_steps, 1, "--golden-envs x --golden-steps")
    if not args.out.strip():  # Path("") is ".": it would write into the current directory
        raise ValueError("--out '' is empty: name the export directory")
    check_new_export_dir(args.out)  # before any work
    sign_key = None if args.sign_key is None else read_key(args.sign_key, "--sign-key")
    key = seed_key(args.seed)
    cfg, row, actor = load_actor(args.source, args.agent)  # run.json checked, its advisor too
    advisor = load_run(args.source)[1].get("advisor")  # None: a run of an older version
    env = envs.make_env(cfg.arena, motion=cfg.motion, max_episode_steps=cfg.max_episode_steps)
    policy_apply = make_actor(cfg.agent.actor_hidden).apply
    obs = rollout_observations(env, policy_apply, actor, key, args.golden_envs, args.golden_steps)
    config_meta = {
        "agent": cfg.agent.name,
        "source": str(args.source),
        "agent_index": args.agent,
        "seed": row["seed"],
        "hparams": {k: row[k] for k in HPARAM_NAMES if k in row},  # older runs lack newer ones
        "train_config": dataclasses.asdict(cfg),
        "advisor": advisor,  # the advisor it was trained with (docs/advisors.md)
    }
    meta = export_policy(
        actor,
        args.out,
        actor_hidden=cfg.agent.actor_hidden,
        env_meta=env.metadata(),
        config_meta=config_meta,
        golden_obs=obs,
        onnx=args.onnx,
        sign_key=sign_key,
    )
    signed = "" if sign_key is None else ", signed"
    print(f"exported agent {args.agent} ({cfg.agent.name}) of {args.source} to {args.out}/{signed}")
    return meta
