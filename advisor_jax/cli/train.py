"""``advisor-jax train``: train a population (seeds × hyperparameter grid) in one compile,
or brax's SAC / PPO seed after seed (``--agent brax-SAC``, ``training/brax_baselines``)."""

from __future__ import annotations

import datetime
from pathlib import Path

from advisor_jax.agent.brax_agents import brax_agent_name
from advisor_jax.cli.helptext import flowing
from advisor_jax.training.request import TrainArgs, build_run

flowing(TrainArgs)  # one paragraph per option at any width (cli/helptext.py)

__all__ = ["RUN_FILES", "TrainArgs", "build_run", "default_out", "train_command", "written"]

# What a finished run directory may hold, in the order the closing line names them.
RUN_FILES = ("run.json", "eval.json", "metrics.npz", "episodes.csv", "train_log.jsonl",
             "params/", "learning_curve.png", "diagnostics.png")  # fmt: skip


def default_out(agent: str, preset_name: str) -> Path:
    stamp = datetime.datetime.now(datetime.UTC).strftime("%Y%m%d-%H%M%S")
    name = agent.replace("+", "_").lower()
    return Path("runs") / f"{name}-{preset_name}-{stamp}"


def written(out: Path) -> str:
    """The closing line: the run's files that exist."""
    present = [f for f in RUN_FILES if (out / f.rstrip("/")).exists()]
    return f"results in {out}/ ({', '.join(present)})"


def train_command(args: TrainArgs) -> None:
    """Entry point of ``advisor-jax train``."""
    if brax_agent_name(args.agent) is not None:
        _brax_command(args)
        return
    cfg, base_hp, grid, seeds, arenas = build_run(args)
    if args.devices is not None and args.devices <= 0:
        raise ValueError(f"--devices must be a positive integer, got {args.devices}")
    multi_host = (args.coordinator, args.num_processes, args.process_id)
    if args.distributed or any(v is not None for v in multi_host):
        from advisor_jax.training.devices import initialize_distributed

        initialize_distributed(*multi_host)  # before any other JAX call
    from advisor_jax.training.host_loop import run_training  # imports JAX: keep --help fast
    from advisor_jax.training.tracking import make_tracker

    out = Path(args.out) if args.out is not None else default_out(cfg.agent.name, args.preset)
    tracker = make_tracker(args.tensorboard, args.wandb, out.name, {"agent": cfg.agent.name})
    try:
        run_training(
            cfg,
            base_hp,
            grid,
            seeds,
            out,
            eval_episodes=args.eval_episodes,
            eval_arenas=arenas,
            checkpoint_every=args.checkpoint_every,
            drop_checkpoints=args.drop_checkpoints,
            resume=args.resume,
            progress=not args.no_progress,
            meta={"preset": args.preset},  # run_training records the program it builds
            chunk_program=None if args.program == "auto" else args.program,
            devices=args.devices,
            eval_seed=args.eval_seed,
            tracker=tracker,
            eval_advisor=args.eval_advisor,
        )
    finally:
        tracker.close()
    print(written(out))


def _brax_command(args: TrainArgs) -> None:
    """``--agent brax-SAC`` / ``brax-PPO``: brax's own trainers, one seed after another."""
    from advisor_jax.training.brax_baselines.request import build_brax_run

    request = build_brax_run(args, default_out)
    from advisor_jax.training.brax_baselines.run import run_brax_training
    from advisor_jax.training.tracking import make_tracker

    tracker = make_tracker(args.tensorboard, args.wandb, request.out.name,
                           {"agent": request.agent})  # fmt: skip
    try:
        run_brax_training(request, progress=not args.no_progress, tracker=tracker)
    finally:
        tracker.close()
    print(written(request.out))
