"""What to train, as ``advisor-jax train`` and a study's pieces ask for it: ``TrainArgs`` (the
options, with their help) and ``build_run`` (options -> the checked static config,
hyperparameters, grid, seeds and evaluation arenas, before anything compiles)."""

from __future__ import annotations

import dataclasses
from typing import Annotated, Literal

import tyro

from advisor_jax.agent.baselines import (
    BASELINE_AGENTS,
    BASELINE_KEYS,
    BASELINE_NAMES,
    check_baseline_hparams,
    check_hparam_names,
    parse_baseline_settings,
)
from advisor_jax.agent.config import PRESETS, preset
from advisor_jax.agent.hparams import PRIOR_HPARAMS, HParams
from advisor_jax.agent.settings import describe, replace_flat
from advisor_jax.training.limits import check_agents, check_episodes
from advisor_jax.training.population import (
    SEED_MAX,
    build_population,
    check_seed,
    parse_assignments,
)


def _preset_help() -> str:
    return "Starting point: " + "; ".join(f"{p.name}: {p.help}" for p in PRESETS.values()) + "."


def _hparams_help(what: str) -> str:
    """``what``, then every hyperparameter as declared (``settings.describe``)."""
    parts = [what, "Hyperparameters (NAME: meaning. value in paper (other presets), range):"]
    parts += describe(HParams)
    for kind, cls in PRIOR_HPARAMS.items():
        parts.append(f"{BASELINE_NAMES[kind]} only:")
        parts += [line for line in describe(cls) if line not in parts]
    return "\n".join(parts)


def _baseline_help() -> str:
    keys = "; ".join(
        f"{', '.join(k)} ({BASELINE_NAMES[kind]})" for kind, k in BASELINE_KEYS.items()
    )
    return (
        f"Baseline static settings KEY=VALUE: {keys}; e.g. --baseline learner=td3 "
        "bc_steps=2000 or model_hidden=500,500. learner is ddpg or td3. Sweepable settings "
        "are hyperparameters (--hp/--grid). brax-SAC and brax-PPO take their brax settings "
        "(docs/baselines.md), e.g. --baseline learning_rate=1e-3 hidden=128,128."
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

    preset: Annotated[Literal[tuple(PRESETS)], tyro.conf.arg(help=_preset_help())] = "quick"
    agent: str = "ATD3+AfDP"
    """Agent type: DDPG, ADDPG, TD3 or ATD3, optionally +AfD, +AfP or +AfDP (Table 1), or
    a baseline (docs/baselines.md): LfD (advisor demonstrations, imitation, then DDPG),
    MCP+MF (random data, dynamics model, MPC rounds, imitation of the MPC with DAgger, then
    DDPG), or brax's own trainers brax-SAC and brax-PPO (seeds one after another, each
    stopped at --episodes; settings via --baseline KEY=VALUE)."""
    seeds: int = 1
    """Independent seeds per grid point."""
    seed: int = 0
    """First seed; the seeds are seed, seed+1, ..."""
    hp: Annotated[
        tuple[str, ...],
        tyro.conf.arg(help=_hparams_help(
            "Hyperparameter overrides NAME=VALUE, e.g. --hp lr_actor=1e-4 beta=0.05.")),
    ] = ()  # fmt: skip
    grid: Annotated[
        tuple[str, ...],
        tyro.conf.arg(help="Hyperparameter sweep NAME=V1,V2,... (cartesian product over all "
                      "given names); the names --hp takes."),
    ] = ()  # fmt: skip
    baseline: Annotated[tuple[str, ...], tyro.conf.arg(help=_baseline_help())] = ()
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
    advisor: str | None = None
    """The advisor (docs/advisors.md): rule (the paper's Algorithm A1, the default), a
    registered name, MODULE:FUNCTION, a training run RUN[:AGENT] or an export directory.
    Its quality knobs are hyperparameters: --grid advisor_random=0,0.2,0.4."""
    precision: Literal["fp32", "bf16"] = "fp32"
    """Compute precision of the learner's hidden layers: fp32, or bf16 matmul inputs and
    activations with fp32 parameters, Adam and accumulation (on GPUs Adam's first moment
    in bf16; faster on GPUs with bf16 tensor cores: results/bench_learner_cublas/; acting is
    always fp32). Recommended for GPU sweeps of these agents: 16 paired seeds of ATD3+AfDP
    and of DDPG at --preset stable learn the same in bf16 (results/precision_study.md);
    other agent types and presets are not checked."""
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
    program: Literal["auto", "general", "steady", "latency-bound"] = "auto"
    """The chunk's compiled program (training/program.py): auto picks it from the population,
    its devices, their memory and the precision; general (a conditional per step for warm-up
    and the TD3 delay), steady (no conditional in the loop past warm-up) or latency-bound
    (the steady program with overlapping kernels: more memory). They compute the same steps
    up to float rounding; recorded in run.json (auto: the program it picked)."""
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
    eval_advisor: bool = False
    """Also evaluate each agent's advisor alone (under its quality knobs) on the same
    evaluation episodes: eval_advisor.json."""
    eval_arenas: tuple[str, ...] | None = None
    """Evaluation arenas (default: training and validation; physical for the physical preset)."""
    eval_seed: int | None = None
    """Seed of the evaluation episodes (default: the first training seed). Give runs that
    are to be pooled the same one: their agents are then evaluated on the same episodes."""
    checkpoint_every: int = 10
    """Write a resumable checkpoint every this many chunks (0 = only at the end)."""
    drop_checkpoints: bool = False
    """Once the run has finished (parameters and evaluation written), delete its checkpoints/:
    a finished run never resumes, and its last checkpoint holds every agent's replay buffer
    and optimizer state (48 `stable` agents: 843 MiB, where params/ holds 362 MiB)."""
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
    tensorboard: Annotated[str | None, tyro.conf.arg(metavar="DIR")] = None
    """Also write every chunk's metrics (population means and each agent's) as TensorBoard
    event files into DIR (view with: tensorboard --logdir DIR). The run directory stays the
    record."""
    wandb: Annotated[str | None, tyro.conf.arg(metavar="PROJECT")] = None
    """Also log them to this Weights & Biases project (needs: pip install wandb; wandb
    login)."""


def build_run(args: TrainArgs):
    """(TrainConfig, base HParams, grid, seeds, eval arenas) from the command line."""
    if args.preset not in PRESETS:
        raise ValueError(f"unknown preset {args.preset!r}; choose one of {', '.join(PRESETS)}")
    if args.seeds <= 0:
        raise ValueError(f"--seeds must be a positive integer, got {args.seeds}")
    check_agents(args.seeds)  # before the list of seeds is built
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
                     "max_episode_steps", "chunk_steps", "snapshot_episodes", "motion",
                     "advisor")
        if getattr(args, name) is not None
    }  # fmt: skip
    cfg = dataclasses.replace(cfg, **train_overrides)
    check_episodes(cfg.episodes)
    if cfg.advisor != "rule":  # an unknown one fails here, before anything is written
        from advisor_jax.training.advisor_source import resolve_advisor

        resolve_advisor(cfg.advisor, _arena(cfg), check=False)
    overrides = parse_assignments(args.hp, "--hp")
    for name, values in overrides.items():
        if len(values) != 1:
            raise ValueError(f"--hp {name} takes one value; use --grid to sweep several")
    grid = parse_assignments(args.grid, "--grid")
    # A baseline hyperparameter of another agent (demo_episodes for DDPG or MCP+MF): an
    # unknown baseline setting; episode counts against N_total per grid point, before
    # compiling.
    check_hparam_names(cfg.agent.baseline, [*overrides, *grid], args.agent)
    base_hp = replace_flat(base_hp, **{k: v[0] for k, v in overrides.items()})
    both = sorted(set(overrides) & set(grid))
    if both:
        raise ValueError(
            f"{', '.join(both)} given to both --hp and --grid (the grid would override --hp); "
            "give each name once"
        )
    seeds = list(range(args.seed, args.seed + args.seeds))
    hp_check = build_population(base_hp, grid, seeds)[0] if grid else base_hp
    check_baseline_hparams(
        cfg.agent.baseline, cfg.episodes, hp_check, {**grid, **overrides}, args.agent
    )
    arenas = args.eval_arenas or (
        ("physical",) if cfg.arena == "physical" else ("training", "validation")
    )
    return cfg, base_hp, grid, seeds, tuple(arenas)


def _arena(cfg):
    import envs

    if cfg.arena not in envs.ARENAS:
        raise ValueError(f"unknown arena {cfg.arena!r}; choose from {', '.join(envs.ARENAS)}")
    return envs.make_env(cfg.arena, max_episode_steps=cfg.max_episode_steps)
