"""The ``advisor-jax`` console script: one tyro subcommand per function in ``SUBCOMMANDS``.

    advisor-jax arena training --xml training.xml          # standalone MJCF of an arena
    advisor-jax arena procedural --seed 3 --xml p3.xml      # a procedural layout
    advisor-jax evaluate --policy advisor --arena validation --episodes 500 [--json]
    advisor-jax train [--preset quick|paper|physical] [--agent ATD3+AfDP] [--seeds N] [--grid ...]
    advisor-jax evaluate --policy runs/NAME:0 --arena validation   # agent 0 of a run
    advisor-jax reevaluate runs/A runs/B --eval-seed 8 --episodes 50   # other episodes
    advisor-jax export runs/NAME --agent 0 --out policy/ [--onnx]
    advisor-jax sweep experiments/studies/quick.toml --out runs/quick [--dry-run]
    advisor-jax report runs/quick --out reports/quick

To add a subcommand, write a function with type-hinted keyword arguments and a docstring
(tyro turns them into flags and ``--help``) and add it to ``SUBCOMMANDS``. ``main`` turns
every ``ValueError``, ``OSError``, runner error and out-of-memory error into one red
``error: ...`` line and exit status 2, and an interrupt (Ctrl-C, or SIGTERM / SIGHUP while
training) into one line saying where it stopped and how to continue, with status 128 + the
signal number, never a traceback. JAX, MuJoCo and the environments are imported
inside the commands, so ``--help`` stays quick.
"""

from __future__ import annotations

import contextlib
import json as jsonlib
import os
import signal
import sys
import threading
from collections.abc import Callable, Sequence
from pathlib import Path
from typing import Annotated, Any

import tyro
from rich.console import Console
from rich.table import Table
from rich.text import Text

from advisor_jax.cli.export import ExportArgs, export_command
from advisor_jax.cli.helptext import flowing
from advisor_jax.cli.report import ReportArgs, report_command
from advisor_jax.cli.sweep import SweepArgs, sweep_command
from advisor_jax.cli.train import TrainArgs, train_command
from advisor_jax.fileio import atomic_create_bytes, atomic_write_json
from advisor_jax.runner.errors import RunnerError


def _envs():
    """Imports ``envs``. MuJoCo's MJX prints "Failed to import warp" on stdout when the
    optional warp back end is absent; send it to stderr so ``--json`` output stays JSON."""
    with contextlib.redirect_stdout(sys.stderr):
        import envs
    return envs


@flowing
def arena(
    name: Annotated[str, tyro.conf.Positional, tyro.conf.arg(metavar="NAME")],
    xml: Path,
    seed: int = 0,
    motion: str = "kinematic",
) -> None:
    """Write an arena as a standalone MuJoCo XML file (loads in plain MuJoCo and the viewer).

    Args:
      name: Arena: training, validation, physical or procedural.
      xml: Output file, a new one (an existing file is never overwritten).
      seed: Procedural arena only: write the layout of the first episode of
        env.reset(key of seed), as drawn in training and evaluation.
      motion: Motion model: kinematic, or mjx (adds the robot's mass, wheels and
        actuators, which CPU MuJoCo can step).
    """
    from advisor_jax.training.population import seed_key

    env = _envs().make_env(name, motion=motion)
    boxes = env.layout_boxes(seed_key(seed)) if env.procedural else None
    text = env.xml(boxes)
    atomic_create_bytes(xml, text.encode())  # a new file; OSError: 'cannot write <xml>: <why>'
    Console(stderr=True).print(Text(f"wrote {xml} ({env.arena_name}, {len(text)} bytes)"))


@flowing
def evaluate(
    policy: str = "advisor",
    arena: str = "training",
    episodes: int | None = None,
    seed: int | None = None,
    eval_seed: int | None = None,
    json: bool = False,
    motion: str | None = None,
    advisor: str = "rule",
    hp: tuple[str, ...] = (),
) -> dict:
    """Evaluate a policy (no exploration noise) over many episodes at once.

    Runs all episodes as parallel environments (each one's first episode counts) and
    prints the success, collision and timeout rates and the mean collision speed. A run's
    agent (RUN:AGENT) is scored by default on the episodes of its own eval.json, so the
    numbers repeat the run's.

    Args:
      policy: advisor (the advisor of --advisor as the trainer consults it, under the
        quality knobs of --hp), a training run directory RUN[:AGENT] (agent index,
        default 0; brax-SAC and brax-PPO runs too) or an export directory.
      arena: Arena: training, validation, physical or procedural.
      episodes: Number of test episodes (default: for a run, as many as its eval.json
        holds for this arena; otherwise 500, the paper's count for the advisor).
      seed: Seed of the episodes' starts, goals (and procedural layouts), and of a noisy
        advisor's draws (default 0; not the key of a run's evaluation: see --eval-seed).
      eval_seed: Score on the episodes that train --eval-seed S scores its agents on
        (default for a run: its own, the episodes of its eval.json).
      json: Print one JSON object instead of a table.
      motion: Motion model: kinematic, mjx or mjx:KEY=VALUE,... Default: the model the
        policy was trained with (a run's or an export's), kinematic for the advisor; another
        one evaluates the policy out of its training conditions, with a warning.
      advisor: With --policy advisor: rule (the paper's Alg. A1), a registered name,
        MODULE:FUNCTION, RUN[:AGENT] or an export directory (docs/advisors.md).
      hp: With --policy advisor: its quality knobs NAME=VALUE, e.g. advisor_noise=0.2
        advisor_delay=3 (advisor_noise, advisor_random, advisor_blind, advisor_range,
        advisor_delay; advisor-jax train --help explains them).
    """
    import jax

    from advisor_jax.cli.policy_spec import RunSpec, parse_policy, resolve_policy
    from advisor_jax.training.limits import check_eval_episodes
    from advisor_jax.training.population import eval_key, seed_key

    if seed is not None and eval_seed is not None:
        raise ValueError("give --seed or --eval-seed, not both")
    quality = _quality(hp, policy, advisor)
    run = parse_policy(policy)
    run = run if isinstance(run, RunSpec) else None
    if episodes is None:
        episodes = run.eval_episodes.get(arena, 500) if run else 500
    check_eval_episodes(episodes, 1, "--episodes")
    from advisor_jax.cli.policy_spec import policy_motion

    if run is not None and seed is None and eval_seed is None:
        eval_seed = run.eval_seed
    # before compiling: a bad seed fails fast
    key = eval_key(eval_seed) if eval_seed is not None else seed_key(seed or 0)
    envs = _envs()
    trained = policy_motion(policy)
    env = envs.make_env(arena, motion=motion or trained or "kinematic",
                        max_episode_steps=run.max_episode_steps if run else 0)  # fmt: skip
    if motion is not None and trained is not None:
        as_trained = envs.EnvConfig(**envs.parse_motion(trained)).motion_setting
        if as_trained != env.config.motion_setting:
            Console(stderr=True).print(
                Text(f"warning: {policy} was trained with motion {as_trained!r}; evaluating "
                     f"it with {env.config.motion_setting!r}", style="yellow")
            )  # fmt: skip
    from advisor_jax.evaluation.evaluate import make_evaluate, summary

    apply, params = resolve_policy(policy, env, advisor, quality)
    evaluate_fn = jax.jit(make_evaluate(env, apply, episodes))
    status = Console(stderr=True)
    if run is not None and eval_seed == run.eval_seed and episodes == run.eval_episodes.get(arena):
        status.print(f"the episodes of {run.directory}/eval.json (eval seed {eval_seed}, "
                     f"{episodes} in {arena}): its numbers for agent {run.index}",
                     soft_wrap=True, highlight=False)  # fmt: skip
    with status.status(f"compiling and running {episodes} episodes of {arena} (h_max = "
                       f"{env.max_episode_steps}) ..."):  # fmt: skip
        metrics = jax.block_until_ready(evaluate_fn(params, key))
    which = {"eval_seed": eval_seed} if eval_seed is not None else {"seed": seed or 0}
    result = {"policy": policy, "arena": arena, "motion": env.config.motion_setting, **which,
              **summary(metrics)}  # fmt: skip
    if policy == "advisor":
        from advisor_jax.agent.settings import flat_items
        from advisor_jax.training.advisor_source import resolve_advisor

        result["advisor"] = resolve_advisor(advisor, env, check=False).record()
        result["quality"] = {k: float(v) for k, v in flat_items(params).items()}
    if json:
        print(jsonlib.dumps(result))
    else:
        _print_table(result)
    return result


def _quality(hp: Sequence[str], policy: str, advisor: str):
    """The advisor's quality knobs from --hp (only with --policy advisor)."""
    if policy != "advisor":
        if hp or advisor != "rule":
            raise ValueError(
                "--advisor and --hp choose the advisor: use them with --policy advisor"
            )
        return None
    from advisor_jax.agent.advisor_quality import AdvisorQuality
    from advisor_jax.agent.settings import flat_fields, replace_flat, validate
    from advisor_jax.training.population import parse_assignments

    values = parse_assignments(hp, "--hp")
    knobs = flat_fields(AdvisorQuality())
    for name, given in values.items():
        if name not in knobs:
            raise ValueError(
                f"--hp {name}: not an advisor quality knob; choose from {', '.join(knobs)}"
            )
        if len(given) != 1:
            raise ValueError(f"--hp {name} takes one value")
    quality = replace_flat(AdvisorQuality(), **{k: v[0] for k, v in values.items()})
    validate(quality)
    return quality


def _print_table(result: dict) -> None:
    name = result["policy"]
    if "advisor" in result:
        from advisor_jax.agent.advisor_quality import changed_knobs

        name = ", ".join(
            [f"advisor {result['advisor']['spec']}", *changed_knobs(result["quality"])]
        )
    table = Table(title=f"{name} in {result['arena']} ({result['episodes']} episodes)")
    table.add_column("metric")
    table.add_column("value", justify="right")
    for key in ("success_rate", "collision_rate", "timeout_rate"):
        table.add_row(key.replace("_", " "), f"{100 * result[key]:.1f} %")
    speed = result["mean_collision_speed"]
    table.add_row("mean collision speed", "n/a" if speed is None else f"{speed:.3f} m/s")
    table.add_row("mean episode length", f"{result['mean_length']:.1f} steps")
    table.add_row("mean return", f"{result['mean_return']:.2f}")
    Console().print(table)


@flowing
def reevaluate(
    runs: Annotated[
        tuple[Path, ...],
        tyro.conf.Positional,
        tyro.conf.arg(metavar="RUN [RUN ...]", help_behavior_hint="(required)"),
    ],
    eval_seed: int,
    episodes: int = 100,
    arenas: tuple[str, ...] = (),
    out: Path | None = None,
) -> None:
    """Score every agent of finished runs again, on the episodes of another evaluation seed.

    Runs trained with different --eval-seed cannot be pooled or paired by advisor-jax
    report; this writes eval_seed<S>.json (eval.json's format) into each run directory,
    and report then scores the run on those episodes.

    Args:
      runs: Finished run directories (their saved actors are evaluated).
      eval_seed: The seed whose episodes to use: those train --eval-seed S scores on.
      episodes: Episodes per arena (the other runs' count, to pool with them).
      arenas: Arenas (default: those of each run's own evaluation).
      out: Write OUT/<run name>/eval_seed<S>.json instead of into each run.
    """
    from advisor_jax.training.run_directory import reevaluate as score_again

    if not runs:
        raise ValueError("reevaluate: name at least one finished run directory (RUN ...)")
    console = Console(stderr=True, highlight=False)
    for run in runs:
        result = score_again(run, eval_seed, episodes, tuple(arenas))
        where = (out / run.name) if out else run
        written = atomic_write_json(where / f"eval_seed{eval_seed}.json", result)
        means = {
            arena: 100 * sum(v for v in r["success"] if v is not None) / len(r["success"])
            for arena, r in result.items()
        }
        success = ", ".join(f"{a} {m:.1f}" for a, m in means.items())
        console.print(
            Text(f"{written}: eval seed {eval_seed}, mean success % {success}"), soft_wrap=True
        )


def train(args: Annotated[TrainArgs, tyro.conf.arg(name="")]) -> None:
    """Train a population of advisor-based agents (seeds × hyperparameter grid, one compile).

    Writes run.json, params/, metrics.npz, episodes.csv, eval.json and learning_curve.png
    into --out; interrupted runs continue with --resume.
    """
    train_command(args)


def export(args: Annotated[ExportArgs, tyro.conf.arg(name="")]) -> None:
    """Export one trained agent for the numpy car runner (policy.npz/json, golden.npz)."""
    export_command(args)


def sweep(args: Annotated[SweepArgs, tyro.conf.arg(name="")]) -> None:
    """Train study files (agent types × static settings × grid × seeds) on every local GPU.

    Plans each study into pieces that fit one device, runs them (resumable: a second call
    skips finished pieces; --time-limit starts only what ends in time), or writes a Slurm
    job array (--slurm). docs/sweeps.md.
    """
    sweep_command(args)


def report(args: Annotated[ReportArgs, tyro.conf.arg(name="")]) -> None:
    """Tables 1-3, Figs 6-11 and the ε grid from finished runs, as PNG and JSON files.

    Pools the runs below DIR... (one loader; they must share their evaluation episodes)
    and writes each item they support, with the commands behind its numbers.
    """
    report_command(args)


SUBCOMMANDS: dict[str, Callable[..., Any]] = {
    "train": train,
    "sweep": sweep,
    "report": report,
    "evaluate": evaluate,
    "reevaluate": reevaluate,
    "export": export,
    "arena": arena,
}


def main(argv: Sequence[str] | None = None) -> None:
    """Entry point of ``advisor-jax``; ``argv`` defaults to ``sys.argv[1:]``."""
    try:
        tyro.extras.subcommand_cli_from_dict(
            SUBCOMMANDS,
            prog="advisor-jax",
            description="Advisor-based DDPG/TD3 navigation agents in JAX/MJX "
            "(Wijesinghe et al., Robotics 2023).",
            args=argv,
        )
    except (ValueError, OSError, RunnerError) as err:
        _error_line(" ".join(str(err).split()) or type(err).__name__)
        sys.exit(2)
    except KeyboardInterrupt as err:  # Ctrl-C, or a signal during training (Interrupted)
        previous = _ignore_interrupts()  # a second Ctrl-C must not cut the line below
        signum = getattr(err, "signum", signal.SIGINT)
        detail = getattr(err, "detail", "")
        Console(stderr=True, highlight=False).print(
            Text(f"stopped by {signal.Signals(signum).name} {detail}".strip(), style="bold red"),
            soft_wrap=True,
        )
        for s, handler in previous.items():
            signal.signal(s, handler)
        sys.exit(128 + signum)  # the shell's convention: 130 for SIGINT, 143 for SIGTERM
    except MemoryError:
        _error_line("out of host memory: lower the number of agents, episodes or buffer size")
        sys.exit(2)
    except Exception as err:
        if "RESOURCE_EXHAUSTED" not in str(err):
            raise  # a bug: its traceback is what a report needs
        first = " ".join(str(err).strip().splitlines()[0].split())[:300]
        advice = "lower the number of agents, episodes or buffer size, or use more devices"
        _error_line(f"the device ran out of memory ({first}); {advice}{_memory_share_hint()}")
        sys.exit(2)


def _memory_share_hint() -> str:
    """How to give JAX more of a GPU, while it has its default share (``plan.GPU_SHARE``).
    1,024 paper-size bf16 agents need 68 GiB of an H100's 80 and fit with 95 %
    (results/bench_train_largest/)."""
    from advisor_jax.study.plan import GPU_SHARE

    if "XLA_PYTHON_CLIENT_MEM_FRACTION" in os.environ:
        return ""
    return (f", or let JAX use more of a GPU than its default {GPU_SHARE:.0%} if nothing else "
            "runs on it: XLA_PYTHON_CLIENT_MEM_FRACTION=0.95")  # fmt: skip


def _error_line(message: str) -> None:
    Console(stderr=True, highlight=False).print(
        Text(f"error: {message}", style="bold red"), soft_wrap=True
    )


def _ignore_interrupts() -> dict:
    """Ignores SIGINT and SIGTERM; returns the handlers to restore (main thread only)."""
    if threading.current_thread() is not threading.main_thread():
        return {}
    return {s: signal.signal(s, signal.SIG_IGN) for s in (signal.SIGINT, signal.SIGTERM)}


if __name__ == "__main__":
    main()
