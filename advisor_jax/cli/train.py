"""``advisor-jax train``: train a population (seeds × hyperparameter grid) in one compile."""

from __future__ import annotations

import dataclasses
import datetime
from pathlib import Path
from typing import Annotated, Literal

import tyro

from advisor_jax.agent.baselines import (
    BASELINE_AGENTS,
    check_baseline_hparams,
    parse_baseline_settings,
)
from advisor_jax.agent.config import PRESETS, TrainConfig, preset
from advisor_jax.training.population import (
    SEED_MAX,
    build_population,
    check_seed,
    parse_assignments,
)


@dataclasses.dataclass(frozen=True)
class TrainArgs:
    """Train advisor-based agents. All seeds and grid points run as one vmapped program.

    Examples:
      advisor-jax train                                    # quick CPU run, ATD3+AfDP
      advisor-jax train --preset paper --agent ADDPG+AfD --seeds 6 \
          --grid advisor_episodes=0,125,250,375,500
      advisor-jax train --preset paper --agent LfD --seeds 6 --grid demo_episodes=10,50,250
      advisor-jax train --preset physical --agent MCP+MF --seeds 6 --baseline learner=td3
    """

    preset: Literal["quick", "paper", "stable", "physical"] = "quick"
    """Starting point: quick (small networks, minutes on a CPU), paper (Tables A2/A4,
    simulation), stable (paper with Eq. 2's Â clipped to the action box, a scale-free
    step β = 1 and the TD target clipped to the arena's return bounds: no seed of any
    Table 1 type below the advisor in 16; docs/architecture.md R33-R35), physical (Tables
    A2/A4, physical column, physical arena)."""
    agent: str = "ATD3+AfDP"
    """Agent type: DDPG, ADDPG, TD3 or ATD3, optionally +AfD, +AfP or +AfDP (Table 1), or
    a baseline (docs/baselines.md): LfD (advisor demonstrations, imitation, then DDPG) or
    MCP+MF (random data, dynamics model, MPC rounds, imitation of the MPC with DAgger, then
    DDPG)."""
    seeds: int = 1
    """Independent seeds per grid point."""
    seed: int = 0
    """First seed; the seeds are seed, seed+1, ..."""
    hp: tuple[str, ...] = ()
    """Hyperparameter overrides NAME=VALUE, e.g. --hp lr_actor=1e-4 beta=0.05."""
    grid: tuple[str, ...] = ()
    """Hyperparameter sweep NAME=V1,V2,... (cartesian product over all given names)."""
    baseline: tuple[str, ...] = ()
    """Baseline static settings KEY=VALUE: learner=ddpg|td3, bc_steps, bc_batch,
    critic_warmup (LfD, MCP+MF); model_hidden (e.g. 500,500), model_steps, model_batch,
    mpc_horizon, mpc_candidates, mpc_rounds, dagger_rounds (MCP+MF); e.g. --baseline
    learner=td3 bc_steps=2000. Sweepable settings are hyperparameters (--hp/--grid):
    demo_episodes, bc_lr (LfD); random_episodes, mpc_episodes, dagger_episodes, bc_lr,
    model_lr, model_noise (MCP+MF)."""
    episodes: int | None = None
    """N_total, training episodes per agent (preset default if omitted)."""
    arena: str | None = None
    """Training arena (preset default if omitted)."""
    envs_per_agent: int | None = None
    """Environments per agent (paper: 1)."""
    updates_per_step: int | None = None
    """Gradient updates per environment step (default 1)."""
    max_episode_steps: int | None = None
    """h_max override (default: the arena's, 300 or 150 for physical)."""
    motion: str | None = None
    """Motion model of the arenas: kinematic (default; a unicycle, (V, ω) act at once) or
    mjx (the Pioneer 3-DX's body and wheels stepped by MJX: acceleration, turn-rate and
    speed limits), optionally with parameters, e.g. mjx:wheel_torque_max=0.5. Evaluation,
    export and the car use the model the run trained with (docs/arena_calibration.md)."""
    precision: Literal["fp32", "bf16"] = "fp32"
    """Compute precision of the learner's hidden layers: fp32, or bf16 matmul inputs and
    activations with fp32 parameters, Adam and accumulation (faster on GPUs with bf16
    tensor cores: ×1.79 learner updates and ×1.72 training steps at 64 agents on an H100;
    acting is always fp32). Recommended for GPU sweeps of these agents: 16 paired seeds
    of ATD3+AfDP and of DDPG at --preset stable learn the same in bf16
    (results/precision_study.md); other agent types and presets are not checked."""
    batch_size: int | None = None
    """Minibatch size override."""
    buffer_size: int | None = None
    """Replay capacity override."""
    policy_delay: int | None = None
    """TD3/ATD3 delay d override: actor and target updates every d critic updates
    (Table A4: 4 in simulation, 3 physical). Only for the TD3 family (and baselines whose
    learner is td3)."""
    chunk_steps: int | None = None
    """Environment steps per jitted chunk (progress/checkpoint granularity)."""
    out: Annotated[str | None, tyro.conf.arg(metavar="DIR")] = None
    """Run directory (default: runs/<agent>-<preset>-<UTC time>). Held exclusively while
    the run trains: a second run or --resume into it is refused."""
    eval_episodes: int = 100
    """Evaluation episodes per agent and arena after training (0 = skip)."""
    snapshot_episodes: tuple[int, ...] = ()
    """Also evaluate each agent's actor as it was after this many episodes (each below
    --episodes), on the same episodes, into eval_episode<N>.json: e.g. --episodes 500
    --snapshot-episodes 200 answers for 200 episodes too (the same actor a 200-episode run
    ends with)."""
    eval_arenas: tuple[str, ...] | None = None
    """Evaluation arenas (default: training and validation; physical for the physical preset)."""
    eval_seed: int | None = None
    """Seed of the evaluation episodes (default: the first training seed). Give runs that
    are to be pooled the same one: their agents are then evaluated on the same episodes."""
    checkpoint_every: int = 10
    """Write a resumable checkpoint every this many chunks (0 = only at the end)."""
    resume: bool = False
    """Continue the interrupted run in --out from its last checkpoint."""
    no_progress: bool = False
    """Hide the progress bar."""
    devices: int | None = None
    """Devices that share the agents (default: all that JAX sees, on every host). A
    population that does not divide evenly is padded with frozen agents."""
    distributed: bool = False
    """Several hosts: start JAX's distributed runtime first (jax.distributed.initialize).
    The coordinator, process count and index come from the three options below or, when
    those are left out, from JAX_COORDINATOR_ADDRESS / JAX_NUM_PROCESSES / JAX_PROCESS_ID or
    a SLURM / Open MPI job. Process 0 writes --out (a directory every host can read)."""
    coordinator: str | None = None
    """host:port of process 0's coordinator (implies --distributed)."""
    num_processes: int | None = None
    """Number of processes (hosts) in the job (implies --distributed)."""
    process_id: int | None = None
    """This process's index, 0 .. num_processes - 1 (implies --distributed)."""


def build_run(args: TrainArgs):
    """(TrainConfig, base HParams, grid, seeds, eval arenas) from the command line."""
    if args.preset not in PRESETS:
        raise ValueError(f"unknown preset {args.preset!r}; choose one of {', '.join(PRESETS)}")
    if args.seeds <= 0:
        raise ValueError(f"--seeds must be a positive integer, got {args.seeds}")
    check_seed(args.seed, "--seed")
    if args.seed + args.seeds - 1 > SEED_MAX:
        raise ValueError(
            f"--seed {args.seed} --seeds {args.seeds} runs past the largest seed 2^64 - 1"
        )
    if args.out is not None and not args.out.strip():
        raise ValueError("--out '' is empty: name the run directory (or leave --out out)")
    agent_overrides = {
        k: v
        for k, v in (
            ("batch_size", args.batch_size),
            ("buffer_size", args.buffer_size),
            ("policy_delay", args.policy_delay),
        )
        if v is not None
    }
    if args.precision != "fp32":
        agent_overrides["precision"] = args.precision
    kind = BASELINE_AGENTS.get(args.agent.strip().lower().replace(" ", ""))
    settings = parse_baseline_settings(args.baseline, kind, args.agent)
    cfg, base_hp = preset(args.preset, args.agent, baseline=settings, **agent_overrides)
    if args.policy_delay is not None and not cfg.agent.twin:
        raise ValueError(
            f"--policy-delay {args.policy_delay}: {cfg.agent.name} (algo {cfg.agent.algo}) "
            "updates its actor at every step; the delay d is a TD3/ATD3 setting"
        )
    train_overrides = {
        name: getattr(args, name)
        for name in ("episodes", "arena", "envs_per_agent", "updates_per_step",
                     "max_episode_steps", "chunk_steps", "snapshot_episodes", "motion")
        if getattr(args, name) is not None
    }  # fmt: skip
    cfg = dataclasses.replace(cfg, **train_overrides)
    overrides = parse_assignments(args.hp, "--hp")
    for name, values in overrides.items():
        if len(values) != 1:
            raise ValueError(f"--hp {name} takes one value; use --grid to sweep several")
    base_hp = base_hp.replace(**{k: v[0] for k, v in overrides.items()})
    grid = parse_assignments(args.grid, "--grid")
    both = sorted(set(overrides) & set(grid))
    if both:
        raise ValueError(
            f"{', '.join(both)} given to both --hp and --grid (the grid would override --hp); "
            "give each name once"
        )
    # A baseline HParam of another agent (demo_episodes for DDPG or MCP+MF): an unknown
    # baseline setting; episode counts against N_total per grid point, before compiling.
    seeds = list(range(args.seed, args.seed + args.seeds))
    hp_check = build_population(base_hp, grid, seeds)[0] if grid else base_hp
    check_baseline_hparams(
        cfg.agent.baseline, cfg.episodes, hp_check, {**grid, **overrides}, args.agent
    )
    arenas = args.eval_arenas or (
        ("physical",) if cfg.arena == "physical" else ("training", "validation")
    )
    return cfg, base_hp, grid, seeds, tuple(arenas)


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
    )
    print(f"results in {out}/ (run.json, eval.json, metrics.npz, episodes.csv, params/)")
