"""``advisor-jax train``: train a population (seeds × hyperparameter grid) in one compile."""

from __future__ import annotations

import datetime
from pathlib import Path

from advisor_jax.agent.config import TrainConfig
from advisor_jax.training.request import TrainArgs, build_run

__all__ = ["TrainArgs", "build_run", "default_out", "train_command"]


def default_out(cfg: TrainConfig, preset_name: str) -> Path:
    stamp = datetime.datetime.now(datetime.UTC).strftime("%Y%m%d-%H%M%S")
    name = cfg.agent.name.replace("+", "_").lower()
    return Path("runs") / f"{name}-{preset_name}-{stamp}"


def train_command(args: TrainArgs) -> None:
    """Entry point of ``advisor-jax train``."""
    cfg, base_hp, grid, seeds, arenas = build_run(args)
    if args.devices is not None and args.devices <= 0:
        raise ValueError(f"--devices must be a positive integer, got {args.devices}")
    multi_host = (args.coordinator, args.num_processes, args.process_id)
    if args.distributed or any(v is not None for v in multi_host):
        from advisor_jax.training.devices import initialize_distributed

        initialize_distributed(*multi_host)  # before any other JAX call
    from advisor_jax.training.host_loop import run_training  # imports JAX: keep --help fast

    out = Path(args.out) if args.out is not None else default_out(cfg, args.preset)
    run_training(
        cfg,
        base_hp,
        grid,
        seeds,
        out,
        eval_episodes=args.eval_episodes,
        eval_arenas=arenas,
        checkpoint_every=args.checkpoint_every,
        resume=args.resume,
        progress=not args.no_progress,
        meta={"preset": args.preset},
        devices=args.devices,
        eval_seed=args.eval_seed,
        eval_advisor=args.eval_advisor,
    )
    print(f"results in {out}/ (run.json, eval.json, metrics.npz, episodes.csv, params/)")
