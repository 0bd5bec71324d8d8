"""Issue 16, item 4: does the advisor in policy updating (AfP) help, and at which β?

The study: Eq. 2's β over a log-spaced range, literal (``beta_normalize=0``, the paper) and
scale-free (``beta_normalize=1``, R33), optionally with Â clipped to the action box
(``clip_actor_target``, R34), for each agent type with AfP (ADDPG+AfP, ADDPG+AfDP,
ATD3+AfDP), against the matching controls without AfP (ADDPG+AfD for both ADDPG types,
ATD3+AfD for ATD3+AfDP; trained at the preset's β, literal), ≥ 16 seeds per point, at 500
and at 200 training episodes (sample efficiency is the paper's claim).

    python experiments/afp_study.py plan --max-agents 16 25    # the pieces, device time
    python experiments/afp_study.py train --max-agents 16 25 --runs runs/afp_study --piece 0 3
    python experiments/afp_study.py summarize --runs runs/afp_study --out results

Shorter budgets are snapshots, not runs: every piece trains for the largest ``--episodes``
and keeps each agent's actor of every smaller one (``--snapshot-episodes``; nothing before
episode N depends on N_total, so it is the actor a run of N episodes ends with,
tests/train/test_population.py), evaluated on the same episodes; ``--separate-episodes``
trains a population per budget instead.

Pieces: each (agent type, episodes) population is split into the fewest pieces of at most
``--max-agents`` agents (one number, or one per ``--episodes``), each a sub-grid × a block
of seeds (e.g. seeds 0-4, 5-10 and 11-15 of the same points are three pieces), so that every
piece trains within one 10-minute GPU command. A vmapped population steps until its slowest
agent is done, and a collapsed seed times out at h_max = 300 steps per episode: at 500
episodes only pieces of ≤ 16 agents fit 600 s even then (``plan``'s "worst" column), hence
``--max-agents 16 25`` for the full study. One run directory per piece, named after it.
``train`` skips finished pieces and resumes interrupted ones; ``--stop-after-s`` stops the
running piece in time (a checkpoint, status "interrupted"; a piece whose training is done
is let finish its evaluation) and exits with status 3. ``summarize`` pools the agents of
every finished run directory under ``--runs`` by (agent type, episodes, β, beta_normalize,
clip_actor_target, any other hyperparameter that differs from the preset), whichever pieces
they came from; a seed found twice for one point counts once, and agents trained at other
settings (a ``--grid lr_actor=...`` beside the study) are points of their own, never pooled
with the study's. Every piece is evaluated on the same episodes, keyed by the study's
``--seed`` (``run_training``'s ``eval_seed``): the evaluation set adds no between-piece
noise. The AfP effect against the control at the same settings is a paired difference over
the seeds both share, else a difference of means with a Welch interval.

On the GPU (the ``device`` tool), one piece per command: what comes back is at most eight
files, here the piece's five small files and the three summary files. Once, here, in the
repository root, fetch the wheels the device image lacks (it has jax 0.11.2, jaxlib, numpy;
scipy and matplotlib, which ``run_training`` imports, are not confirmed: the command's
import line says, and a missing one is fetched the same way, with its own dependencies):

    echo /.whl/ >> .git/info/exclude
    python3 -m pip download --no-deps --only-binary=:all: --python-version 3.12 \\
        --implementation cp --platform manylinux_2_28_x86_64 --platform manylinux_2_27_x86_64 \\
        --platform manylinux_2_17_x86_64 --platform manylinux2014_x86_64 -d .whl \\
        mujoco==3.17.0 mujoco-mjx==3.17.0 flax==0.12.8 optax==0.2.8 orbax-checkpoint==0.12.8 \\
        rich==15.0.0 etils==1.15.0 tensorstore==0.1.86 msgpack==1.2.4 treescope==0.1.10 \\
        humanize==4.17.0 simplejson==4.3.0 aiofiles==25.1.0 absl-py==2.5.1 glfw==2.11.0 \\
        pyopengl==3.1.10 trimesh==5.2.0 markdown-it-py==4.3.0 mdurl==0.1.2 pygments==2.20.0 \\
        prometheus-client==0.26.0 websockets==17.4 uvloop==0.23.0

then for piece N (``plan``'s numbering), ``run`` with ``carry: [".whl"]``, ``timeout_s:
600`` and this command (one line; OPTS: the study options, the same in every command, e.g.
``--max-agents 16 25``; the piece stops itself after 540 s):

    python3 -m pip install -q --no-index --no-deps --no-compile --no-cache-dir --upgrade
      --target /tmp/site .whl/*.whl && export PYTHONPATH=/tmp/site:$PWD PYTHONUNBUFFERED=1
      || exit; python3 -c 'import mujoco.mjx, flax, optax, orbax.checkpoint, scipy,
      matplotlib, rich' || exit; python3 experiments/afp_study.py train OPTS --runs
      runs/afp_study --piece N --stop-after-s 540 --export $OUT/pieces; python3
      experiments/afp_study.py summarize --runs runs/afp_study --out $OUT/summary

The study options (``--preset``, ``--agents``, ``--controls``, ``--betas``, ``--modes``,
``--clip``, ``--seeds``, ``--seed``, ``--episodes``, ``--max-agents``, ``--hp``) define the
pieces and their numbers: give ``plan``, ``train`` and every piece's command the same ones.
``--export`` copies only run.json, eval.json, metrics.npz, train_log.jsonl and episodes.csv
of each finished piece (never checkpoints/ or params/: replay buffers and weights). Back
here, copy ``pieces/<piece>/`` of what came back into one folder (e.g.
``results/afp_study/runs/``) and summarize that folder. A piece stopped by
``--stop-after-s`` (exit status 3) resumes only on the machine that holds its checkpoint:
send the same command again at once, while that machine is warm; elsewhere it starts afresh.
"""

from __future__ import annotations

import argparse
import dataclasses
import itertools
import json
import math
import signal
import sys
from pathlib import Path

import common
import numpy as np

AFP_AGENTS = ("ADDPG+AfP", "ADDPG+AfDP", "ATD3+AfDP")
CONTROL_OF = {"ADDPG+AfP": "ADDPG+AfD", "ADDPG+AfDP": "ADDPG+AfD", "ATD3+AfDP": "ATD3+AfD"}
AXES = ("beta", "beta_normalize", "clip_actor_target")  # a study point, with agent and episodes
SHORT = {"beta": "b", "beta_normalize": "n", "clip_actor_target": "c"}
DIAGNOSTICS = ("advisor/replaced", "diag/step", "diag/grad_q_rms", "diag/q_gain", "diag/saturated")
STOPPED = 3  # exit status of a train command stopped by --stop-after-s (resume it)
STOP_MESSAGE = "--stop-after-s"


@dataclasses.dataclass(frozen=True)
class Piece:
    """One run directory of the study: an agent type's sub-grid × a block of seeds."""

    agent: str
    episodes: int
    grid: tuple[tuple[str, tuple[float, ...]], ...]
    seeds: tuple[int, ...]

    @property
    def name(self) -> str:
        axes = "-".join(SHORT[k] + "_".join(f"{v:g}" for v in vs) for k, vs in self.grid)
        return (
            f"{self.agent.replace('+', '_')}-e{self.episodes}-{axes}"
            f"-s{self.seeds[0]}-{self.seeds[-1]}"
        )

    @property
    def n_agents(self) -> int:
        return len(self.seeds) * math.prod(len(vs) for _, vs in self.grid)


def _blocks(values: list, size: int) -> list[list]:
    """``values`` in ceil(n / size) contiguous blocks of nearly equal length (≤ size)."""
    n = math.ceil(len(values) / size)
    bounds = [round(i * len(values) / n) for i in range(n + 1)]
    return [values[a:b] for a, b in itertools.pairwise(bounds)]


def split_population(grid: dict[str, list], seeds: list[int], max_agents: int):
    """A population (``grid`` × ``seeds``) as the fewest pieces of at most ``max_agents``
    agents, each a sub-grid (a block of values per axis: ``run_training`` takes a product)
    × a block of seeds; among splits into as many pieces, the one whose largest piece is
    smallest, then the one that splits seeds least. Returns [(sub-grid, seeds)], seed
    blocks outermost, so the first pieces cover every point with the first seeds."""
    axes = list(grid)
    best = None
    for s in range(1, min(len(seeds), max_agents) + 1):
        seed_blocks = _blocks(seeds, s)
        for sizes in itertools.product(*(range(1, len(grid[a]) + 1) for a in axes)):
            if math.prod(sizes) * s > max_agents:
                continue
            value_blocks = [_blocks(grid[a], b) for a, b in zip(axes, sizes, strict=True)]
            count = len(seed_blocks) * math.prod(len(b) for b in value_blocks)
            largest = max(map(len, seed_blocks)) * math.prod(max(map(len, b)) for b in value_blocks)
            key = (count, largest, -s)
            if best is None or key < best[0]:
                best = (key, seed_blocks, value_blocks)
    _, seed_blocks, value_blocks = best
    return [
        (dict(zip(axes, combo, strict=True)), block)
        for block in seed_blocks
        for combo in itertools.product(*value_blocks)
    ]


def study_pieces(args) -> list[Piece]:
    """Every piece of the study the options describe, in the order to train them: by
    episodes (as given), then seed block, then agent type (controls first)."""
    seeds = list(range(args.seed, args.seed + args.seeds))
    agents = [*args.controls, *args.agents]
    ordered = []
    for e, episodes in enumerate(args.episodes):
        if not args.separate_episodes and episodes != max(args.episodes):
            continue  # a snapshot of the longest pieces (snapshot_budgets)
        max_agents = args.max_agents[e if len(args.max_agents) > 1 else 0]
        for a, agent in enumerate(agents):
            if agent in args.agents:
                grid = {"beta": args.betas, "beta_normalize": args.modes}
            else:
                grid = {}
            grid["clip_actor_target"] = args.clip
            for p, (sub, block) in enumerate(split_population(grid, seeds, max_agents)):
                key = (e, block[0], a, p)
                frozen = tuple((k, tuple(float(v) for v in vs)) for k, vs in sub.items())
                ordered.append((key, Piece(agent, episodes, frozen, tuple(block))))
    return [piece for _, piece in sorted(ordered, key=lambda kp: kp[0])]


def snapshot_budgets(args, episodes: int) -> tuple[int, ...]:
    """The smaller ``--episodes`` a piece of ``episodes`` keeps actors of (none when every
    budget trains its own pieces)."""
    if args.separate_episodes:
        return ()
    return tuple(sorted(e for e in set(args.episodes) if e < episodes))


def _check_options(args) -> None:
    unknown = [a for a in args.agents if a not in CONTROL_OF]
    if unknown:
        sys.exit(f"--agents: {', '.join(unknown)} not an AfP agent type ({', '.join(AFP_AGENTS)})")
    if args.controls is None:
        args.controls = sorted(
            {CONTROL_OF[a] for a in args.agents}, key=list(CONTROL_OF.values()).index
        )
    if any(m not in (0.0, 1.0) for m in args.modes + args.clip):
        sys.exit("--modes and --clip are 0/1 switches")
    if len(args.max_agents) not in (1, len(args.episodes)) or min(args.max_agents) < 1:
        sys.exit("--max-agents: one positive number, or one per --episodes")
    try:
        args.hp_values = common.hp_overrides(args.hp)
    except ValueError as e:
        sys.exit(str(e))
    clash = sorted(set(args.hp_values) & set(AXES))
    if clash:
        sys.exit(f"--hp {', '.join(clash)}: the study sweeps it (--betas, --modes, --clip)")


def _study_argv(args) -> list[str]:
    """The options that define the pieces, as given (for the commands written down)."""
    argv = [
        "--preset",
        args.preset,
        "--agents",
        *args.agents,
        "--controls",
        *args.controls,
        "--betas",
        *(f"{b:g}" for b in args.betas),
        "--modes",
        *(f"{m:g}" for m in args.modes),
        "--clip",
        *(f"{c:g}" for c in args.clip),
        "--seeds",
        args.seeds,
        "--seed",
        args.seed,
        "--episodes",
        *args.episodes,
        "--eval-episodes",
        args.eval_episodes,
        "--max-agents",
        *args.max_agents,
    ]
    if args.separate_episodes:
        argv.append("--separate-episodes")
    for item in args.hp:
        argv += ["--hp", item]
    return [str(a) for a in argv]


# -- plan -----------------------------------------------------------------------------------


def plan(args) -> None:
    from advisor_jax.agent.config import preset
    from envs.layouts import ARENA_SPECS

    pieces = study_pieces(args)
    cfg = preset(args.preset, pieces[0].agent)[0]
    h_max = cfg.max_episode_steps or ARENA_SPECS[cfg.arena].h_max
    rows, total, worst_total = [], 0.0, 0.0
    too_long = []
    for i, p in enumerate(pieces):
        steps = p.n_agents * p.episodes
        est = steps * args.steps_per_episode / args.agent_steps_per_s + args.overhead_s
        worst = steps * h_max / args.agent_steps_per_s + args.overhead_s
        total += est
        worst_total += worst
        if worst > args.limit_s:
            too_long.append(i)
        grid = ", ".join(f"{k}={','.join(f'{v:g}' for v in vs)}" for k, vs in p.grid)
        seeds = f"{p.seeds[0]}-{p.seeds[-1]}"
        rows.append((i, p.agent, p.episodes, grid, seeds, p.n_agents, est, worst, p.name))
    lines = [
        f"# AfP study plan: {len(pieces)} pieces, {sum(p.n_agents for p in pieces)} agents",
        "",
        f"Preset `{args.preset}`; est. = agents × episodes × {args.steps_per_episode:g} steps / "
        f"{args.agent_steps_per_s:g} agent env-steps/s + {args.overhead_s:g} s (compile, "
        f"evaluation, files); worst = every episode of the slowest agent at h_max = {h_max} "
        "steps (the vmapped population steps until its last agent is done).",
        "",
        *common.markdown_table(
            ("#", "agent", "episodes", "grid", "seeds", "agents", "est. s", "worst s", "run dir"),
            rows,
            formats=("", "", "", "", "", "", ".0f", ".0f", ""),
            align="rllllrrrl",
        ),
        "",
    ]
    for episodes in args.episodes:
        sub = [r for r in rows if r[2] == episodes]
        lines.append(
            f"- {episodes} episodes: {len(sub)} pieces, {sum(r[5] for r in sub)} agents, "
            f"est. {sum(r[6] for r in sub) / 3600:.2f} h of device time "
            f"(worst {sum(r[7] for r in sub) / 3600:.2f} h)"
        )
    lines += [
        f"- **total: est. {total / 3600:.2f} h of device time** ({total / 60:.0f} min; worst "
        f"{worst_total / 3600:.2f} h) in {len(pieces)} GPU commands of at most "
        f"{args.limit_s:g} s, plus each command's machine start and wheel installation",
    ]
    if too_long:
        lines.append(
            f"- pieces {', '.join(map(str, too_long))} could outrun {args.limit_s:g} s "
            "in the worst case: give them `--stop-after-s` and resend the command at once "
            "to resume (or lower `--max-agents`)"
        )
    lines += [
        "",
        'GPU command for piece N (``device`` tool, `carry: [".whl"]`, `timeout_s: 600`; '
        "see the module docstring):",
        "",
        "    " + gpu_command(args),
    ]
    print("\n".join(lines))


def gpu_command(args, piece: str = "N") -> str:
    """The one-line command that trains one piece on a bare GPU machine and brings back its
    small files and a summary of it (module docstring)."""
    train = (
        common.command_line(
            "experiments/afp_study.py",
            [
                "train",
                *_study_argv(args),
                "--runs",
                "runs/afp_study",
                "--piece",
                piece,
                "--stop-after-s",
                "540",
                "--export",
                "OUT_PIECES",
            ],
        )
        .replace("python ", "python3 ", 1)
        .replace("OUT_PIECES", "$OUT/pieces")
    )
    return (
        "python3 -m pip install -q --no-index --no-deps --no-compile --no-cache-dir --upgrade "
        "--target /tmp/site .whl/*.whl && export PYTHONPATH=/tmp/site:$PWD PYTHONUNBUFFERED=1 "
        "|| exit; python3 -c 'import mujoco.mjx, flax, optax, orbax.checkpoint, scipy, "
        f"matplotlib, rich' || exit; {train}; python3 experiments/afp_study.py summarize "
        "--runs runs/afp_study --out $OUT/summary"
    )


# -- train ----------------------------------------------------------------------------------


class _Deadline:
    """``--stop-after-s``: once ``seconds`` have passed (0: never), stops the piece being
    trained at its next chunk (KeyboardInterrupt: ``run_training`` saves a checkpoint and
    marks the run "interrupted", as on Ctrl-C), unless its training loop is done
    (train_log.jsonl: every agent has its episodes; evaluation and files remain), which it
    lets finish; no further piece starts."""

    def __init__(self, seconds: float):
        self.seconds, self.passed, self.piece = seconds, False, None

    def __enter__(self):
        if self.seconds > 0:
            self.previous = signal.signal(signal.SIGALRM, self._fire)
            signal.setitimer(signal.ITIMER_REAL, self.seconds)
        return self

    def __exit__(self, *exc):
        if self.seconds > 0:
            signal.setitimer(signal.ITIMER_REAL, 0)
            signal.signal(signal.SIGALRM, self.previous)

    def _fire(self, signum, frame):
        self.passed = True
        if self.piece is not None and not _loop_done(*self.piece):
            raise KeyboardInterrupt(STOP_MESSAGE)


def _loop_done(run_dir: Path, episodes: int) -> bool:
    """Whether the last line of the run's train_log.jsonl has every agent done."""
    try:
        last = (run_dir / "train_log.jsonl").read_text().splitlines()[-1]
        return json.loads(last)["episodes_min"] >= episodes
    except (OSError, IndexError, ValueError, KeyError):
        return False


def _selected(pieces: list[Piece], chosen: list[str]) -> list[tuple[int, Piece]]:
    if not chosen:
        return list(enumerate(pieces))
    by_name = {p.name: i for i, p in enumerate(pieces)}
    out = []
    for item in chosen:
        i = int(item) if item.isdigit() else by_name.get(item, -1)
        if not 0 <= i < len(pieces):
            sys.exit(
                f"--piece {item}: no such piece (0-{len(pieces) - 1}, or a run dir name; see plan)"
            )
        out.append((i, pieces[i]))
    return out


def train(args) -> None:
    import dataclasses as dc

    from advisor_jax.agent.config import preset
    from advisor_jax.training.runlock import RunDirectoryBusy

    pieces = study_pieces(args)
    selected = _selected(pieces, args.piece)
    with _Deadline(args.stop_after_s) as deadline:
        for i, piece in selected:
            if deadline.passed:
                break
            cfg, hp = preset(args.preset, piece.agent)
            cfg = dc.replace(
                cfg,
                episodes=piece.episodes,
                snapshot_episodes=snapshot_budgets(args, piece.episodes),
            )
            hp = dc.replace(hp, **args.hp_values)
            run_dir = args.runs / piece.name
            argv = ["train", "--runs", str(args.runs), "--piece", str(i), *_study_argv(args)]
            meta = {
                "preset": args.preset,
                "afp_study": {
                    "piece": piece.name,
                    "index": i,
                    "pieces": len(pieces),
                    "command": common.command_line("experiments/afp_study.py", argv),
                },
            }
            print(
                f"piece {i}/{len(pieces)}: {piece.name} ({piece.n_agents} agents)", file=sys.stderr
            )
            deadline.piece = (run_dir, piece.episodes)
            try:
                how = common.train_or_resume(
                    run_dir,
                    cfg,
                    hp,
                    {k: list(vs) for k, vs in piece.grid},
                    piece.seeds,
                    eval_episodes=args.eval_episodes,
                    eval_seed=args.seed,  # one episode set for every piece: paired agents
                    checkpoint_every=args.checkpoint_every,
                    progress=args.progress,
                    meta=meta,
                )
            except RunDirectoryBusy as e:
                print(f"  skipped: {e}", file=sys.stderr)
                continue
            except KeyboardInterrupt as e:
                if str(e) != STOP_MESSAGE:
                    raise
                break
            finally:
                deadline.piece = None
            print(f"  {how}: {run_dir}", file=sys.stderr)
            if args.export:
                common.export_small_files(run_dir, args.export / piece.name)
    left = [(i, common.run_status(args.runs / p.name)) for i, p in selected]
    left = [(i, status) for i, status in left if status != "finished"]
    if deadline.passed and left:
        print(
            f"{STOP_MESSAGE} {args.stop_after_s:g}: time is up; not finished: "
            + ", ".join(f"piece {i} ({status or 'not started'})" for i, status in left)
            + ". Send the same command again to go on (an interrupted piece resumes from its "
            "checkpoint on this machine)",
            file=sys.stderr,
        )
        sys.exit(STOPPED)


# -- summarize ------------------------------------------------------------------------------


def _final_chunk(metrics, index: int, episodes: int | None = None) -> dict[str, float | None]:
    """Each diagnostic's value in the agent's last chunk of training (the chunk in which it
    completed its episodes; later chunks only wait for the rest of the population), or in
    the chunk in which it completed ``episodes`` (a snapshot)."""
    steps = metrics["log/step"] if "log/step" in metrics else np.zeros(0)
    if steps.size == 0:
        return {name: None for name in DIAGNOSTICS}
    done = metrics["env_steps"][index]
    if episodes is not None:  # one env per agent: the steps of its first `episodes` episodes
        done = int(np.sum(metrics["length"][index, :episodes]))
    last = min(int(np.searchsorted(steps, done)), steps.size - 1)
    out = {}
    for name in DIAGNOSTICS:
        key = f"log/{name}"
        values = metrics[key][index, : last + 1] if key in metrics else np.zeros(0)
        finite = values[np.isfinite(values)]
        out[name] = float(finite[-1]) if finite.size else None
    return out


def _beside_axes(settings: dict) -> tuple[tuple[str, float], ...]:
    """The hyperparameters, besides the study's axes, in which an agent differs from its
    preset (e.g. ``(("lr_actor", 4e-05),)``): part of its study point, so that agents
    trained at other settings are never pooled with the study's own."""
    return tuple(sorted((k, v) for k, v in settings.items() if k not in ("preset", "episodes")))


def collect(roots: Path | list[Path]):
    """Agents of every finished run under ``roots`` pooled by study point: {(agent,
    episodes, β, beta_normalize, clip, other settings): {seed: record}}, plus the runs'
    provenance and notes on what was left out (runs of other agent types, e.g. a Table 1
    folder's DDPG). ``other settings`` (``_beside_axes``) is empty for the study's points."""
    runs, notes = [], []
    for root in [roots] if isinstance(roots, Path) else roots:
        found, left_out = common.finished_runs(root)
        runs += found
        notes += left_out
    study_types = {*AFP_AGENTS, *CONTROL_OF.values()}
    for run_dir, summary in [r for r in runs if r[1]["agent"] not in study_types]:
        notes.append(f"{run_dir}: {summary['agent']} is not a study agent type, left out")
    runs = [r for r in runs if r[1]["agent"] in study_types]
    points: dict[tuple, dict[int, dict]] = {}
    settings: dict[tuple, dict] = {}
    where = {"devices": set(), "dates": set(), "eval_episodes": set(), "commands": []}
    for run_dir, summary in runs:
        evaluations = [(summary["config"]["episodes"], None, summary.get("evaluation") or {})]
        evaluations += [  # the actors kept at smaller budgets (snapshot_episodes)
            (int(n), int(n), ev) for n, ev in (summary.get("evaluation_at_episode") or {}).items()
        ]
        if not {"training", "validation"} <= set(evaluations[0][2]):
            notes.append(f"{run_dir}: not evaluated in both arenas, left out")
            continue
        metrics = (
            dict(np.load(run_dir / "metrics.npz")) if (run_dir / "metrics.npz").is_file() else {}
        )
        ev = evaluations[0][2]
        where["devices"].add(summary.get("device", "?"))
        where["dates"].add(summary.get("created", "?")[:10])
        where["eval_episodes"].add(ev["training"]["episodes"])
        command_file = run_dir / "command.json"  # beside a run made on the device tool
        command = (summary.get("afp_study") or {}).get("command") or (
            json.loads(command_file.read_text()).get("command") if command_file.is_file() else None
        )
        if command and command not in where["commands"]:
            where["commands"].append(command)
        for (episodes, snapshot, ev), row in itertools.product(evaluations, summary["agents"]):
            i = row["index"]
            other = {
                k: v for k, v in common.preset_differences(summary, row).items() if k not in AXES
            }
            other["episodes"] = episodes
            key = (summary["agent"], episodes, *(row[a] for a in AXES), _beside_axes(other))
            if settings.setdefault(key, other) != other:
                notes.append(
                    f"{run_dir}: agent {i} differs from the same point elsewhere "
                    f"({other} vs {settings[key]}); pooled anyway"
                )
            seeds = points.setdefault(key, {})
            if row["seed"] in seeds:
                notes.append(
                    f"{run_dir}: seed {row['seed']} of {key} also in "
                    f"{seeds[row['seed']]['run']}; counted once"
                )
                continue
            seeds[row["seed"]] = {
                "run": run_dir.name,
                "snapshot": snapshot is not None,
                "diverged": ev["training"]["success"][i] is None,
                "training": ev["training"]["success"][i],
                "validation": ev["validation"]["success"][i],
                "timeout": ev["training"]["timeout"][i],
                "diagnostics": _final_chunk(metrics, i, snapshot) if metrics else {},
            }
    return points, settings, where, notes


def welch_ci95(a, b) -> tuple[float, float]:
    """mean(a) − mean(b) and the half-width of its Welch 95 % interval (NaN if undefined)."""
    a, b = (np.asarray([v for v in x if v is not None], np.float64) for x in (a, b))
    if a.size < 2 or b.size < 2:
        diff = a.mean() - b.mean() if a.size and b.size else math.nan
        return float(diff), math.nan
    va, vb = a.var(ddof=1) / a.size, b.var(ddof=1) / b.size
    se = math.sqrt(va + vb)
    if se == 0:
        return float(a.mean() - b.mean()), 0.0
    df = (va + vb) ** 2 / (va**2 / (a.size - 1) + vb**2 / (b.size - 1))
    from scipy import stats

    return float(a.mean() - b.mean()), float(stats.t.ppf(0.975, df) * se)


def paired_ci95(afp: dict, control: dict, arena: str) -> dict | None:
    """The AfP point minus its control over the seeds both evaluated (a seed fixes the
    initial networks, the environment stream and, with one eval seed, the evaluation
    episodes): mean difference, Student-t 95 % half-width, seed count; None under 2."""
    from advisor_jax.training.reporting import mean_ci95

    shared = [s for s in afp if s in control]
    diffs = [
        afp[s][arena] - control[s][arena]
        for s in shared
        if afp[s][arena] is not None and control[s][arena] is not None
    ]
    if len(diffs) < 2:
        return None
    mean, half = mean_ci95(diffs)
    return {"diff": mean, "ci95": half, "seeds": len(diffs)}


def _control_key(key: tuple, points: dict) -> tuple | None:
    """The no-AfP point matching an AfP point: its control agent type, same episodes,
    clip_actor_target and other settings (any β: without AfP, β only scales the actor's
    gradient). None where no control was trained at those settings."""
    agent, episodes, _, _, clip, other = key
    control = CONTROL_OF.get(agent)
    matches = [
        k for k in points if k[0] == control and k[1] == episodes and k[4] == clip and k[5] == other
    ]
    return min(matches) if matches else None


def point_stats(points: dict, collapse_below: float) -> list[dict]:
    from advisor_jax.training.reporting import mean_ci95

    out = []
    for key in sorted(points, key=lambda k: (-k[1], k[0], k[5], k[3], k[4], k[2])):
        seeds = dict(sorted(points[key].items()))
        agent, episodes, beta, normalize, clip, other = key
        rec = {
            "agent": agent,
            "episodes": episodes,
            "beta": beta,
            "beta_normalize": normalize,
            "clip_actor_target": clip,
            "other": dict(other),
            "afp": agent in CONTROL_OF,
            "seeds": list(seeds),
            "diverged": [s for s, r in seeds.items() if r["diverged"]],
            "snapshot_seeds": [s for s, r in seeds.items() if r.get("snapshot")],
        }
        for arena in ("training", "validation"):
            values = [r[arena] for r in seeds.values()]
            mean, half = mean_ci95(values)
            collapsed = sum(v is not None and v < collapse_below for v in values)
            rec[arena] = {"per_seed": values, "mean": mean, "ci95": half, "collapsed": collapsed}
        rec["timeout_training"] = mean_ci95([r["timeout"] for r in seeds.values()])[0]
        rec["diagnostics"] = {
            name: mean_ci95([(r["diagnostics"] or {}).get(name) for r in seeds.values()])[0]
            for name in DIAGNOSTICS
        }
        control = _control_key(key, points) if agent in CONTROL_OF else None
        if control is not None:
            rec["control"] = control[0]
            rec["effect"] = {}
            for arena in ("training", "validation"):
                diff, half = welch_ci95(
                    [r[arena] for r in points[key].values()],
                    [r[arena] for r in points[control].values()],
                )
                rec["effect"][arena] = {"diff": diff, "ci95": half}
                rec["effect"][arena]["paired"] = paired_ci95(points[key], points[control], arena)
        out.append(rec)
    return out


def _pct(mean: float, half: float) -> str:
    if math.isnan(mean):
        return "–"
    return f"{100 * mean:.1f}" + ("" if math.isnan(half) else f" ± {100 * half:.1f}")


def _mode(rec: dict) -> str:
    """How the point makes Eq. 2's step, e.g. ``scale-free, clipped``, with the settings
    it has beside the study's axes (``, lr_actor=4e-05``)."""
    if not rec["afp"]:
        mode = "no AfP"
    else:
        mode = "scale-free" if rec["beta_normalize"] else "literal"
        mode += ", clipped" if rec["clip_actor_target"] else ""
    other = rec.get("other", {}).items()
    return mode + "".join(f", {k}={common.setting_text(v)}" for k, v in other)


def _effect(rec: dict, arena: str) -> str:
    """The paired interval where the point and its control share seeds, else Welch's."""
    eff = rec.get("effect", {}).get(arena)
    if eff and eff.get("paired"):
        eff = eff["paired"]
    if not eff or math.isnan(eff["diff"]):
        return "–"
    d, h = 100 * eff["diff"], 100 * eff["ci95"]
    return f"{d:+.1f}" if math.isnan(h) else f"{d:+.1f} [{d - h:+.1f}, {d + h:+.1f}]"


def _num(x) -> str:
    return "–" if x is None or not math.isfinite(x) else f"{x:.3g}"


def _per_seed(values) -> str:
    return " ".join("–" if v is None else f"{100 * v:.0f}" for v in values)


def plot(stats: list[dict], collapse_below: float, path: Path) -> None:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    agents = [a for a in AFP_AGENTS if any(r["agent"] == a for r in stats)]
    episodes = sorted({r["episodes"] for r in stats}, reverse=True)
    columns = [(e, arena) for e in episodes for arena in ("training", "validation")]
    if not agents:
        return
    fig, axes = plt.subplots(
        len(agents),
        len(columns),
        squeeze=False,
        sharey=True,
        figsize=(4.2 * len(columns), 3.3 * len(agents)),
        constrained_layout=True,
    )
    modes = sorted({_mode(r) for r in stats if r["afp"]})
    colors = dict(zip(modes, plt.rcParams["axes.prop_cycle"].by_key()["color"], strict=False))
    betas = sorted({r["beta"] for r in stats if r["afp"]})
    for row, agent in enumerate(agents):
        for col, (e, arena) in enumerate(columns):
            ax = axes[row, col]
            for m, mode in enumerate(modes):
                offset = 10.0 ** (0.12 * (m - (len(modes) - 1) / 2))
                here = [
                    r
                    for r in stats
                    if r["agent"] == agent and r["episodes"] == e and _mode(r) == mode
                ]
                for j, r in enumerate(here):
                    common.seeds_with_ci(
                        ax,
                        r["beta"] * offset,
                        r[arena]["per_seed"],
                        colors[mode],
                        label=None if j else mode,
                        log_x=True,
                        width=0.08,
                    )
            control = sorted(  # the control at the study's own settings first
                (r for r in stats if r["agent"] == CONTROL_OF[agent] and r["episodes"] == e),
                key=lambda r: len(r["other"]),
            )
            for r in control[:1]:
                mean, half = r[arena]["mean"], r[arena]["ci95"]
                half = np.nan_to_num(half)
                ax.axhspan(
                    mean - half,
                    mean + half,
                    color="0.6",
                    alpha=0.3,
                    label=f"{r['agent']} (no AfP), n={len(r['seeds'])}",
                )
                ax.axhline(mean, color="0.4", lw=1)
                common.seeds_with_ci(
                    ax, betas[0] / 4, r[arena]["per_seed"], "0.4", log_x=True, width=0.08
                )
            ax.axhline(collapse_below, color="red", ls="--", lw=0.8, label="collapse line")
            ax.set_xscale("log")
            ax.set_xticks(betas, [f"{b:g}" for b in betas])
            ax.set_ylim(-0.03, 1.03)
            ax.grid(alpha=0.3)
            ax.set_title(f"{agent}, {e} ep, {arena} arena", fontsize=9)
            if row == len(agents) - 1:
                ax.set_xlabel("β (control at the left)")
            if col == 0:
                ax.set_ylabel("success (evaluation)")
            if not any(r["agent"] == agent and r["episodes"] == e for r in stats):
                ax.text(0.5, 0.5, "not trained", transform=ax.transAxes, ha="center")
    handles = {}
    for ax in axes.ravel():
        handles.update(zip(*reversed(ax.get_legend_handles_labels()), strict=True))
    fig.legend(
        list(handles.values()),
        list(handles),
        loc="outside lower center",
        ncol=len(handles),
        fontsize=8,
    )
    fig.suptitle("AfP study: per-seed success (dots), mean ± 95 % CI (bars) vs β")
    from advisor_jax.training.plots import save_png

    save_png(fig, path)


def summarize(args) -> None:
    points, settings, where, notes = collect(args.runs)
    if not points:
        sys.exit(f"no finished runs under {args.runs}")
    stats = point_stats(points, args.collapse_below)
    for rec in stats:
        key = (
            rec["agent"],
            rec["episodes"],
            rec["beta"],
            rec["beta_normalize"],
            rec["clip_actor_target"],
            tuple(rec["other"].items()),
        )
        rec["settings"] = settings[key]
    args.out.mkdir(parents=True, exist_ok=True)
    plot(stats, args.collapse_below, args.out / "afp_study.png")
    eval_episodes = sorted(where["eval_episodes"])
    summarize_cmd = common.command_line(
        "experiments/afp_study.py",
        [
            "summarize",
            "--runs",
            *args.runs,
            "--out",
            args.out,
            *(["--collapse-below", args.collapse_below] if args.collapse_below != 0.5 else []),
        ],
    )
    lines = [
        "# AfP study (issue 16, item 4): β literal and scale-free, against the no-AfP controls",
        "",
        f"Device: {', '.join(sorted(where['devices']))}; "
        f"trained {', '.join(sorted(where['dates']))}. "
        f"Evaluation: deterministic actor, {', '.join(map(str, eval_episodes))} episodes per "
        "arena. Success in %, mean ± half-width of the Student-t 95 % interval over seeds; "
        f"collapsed: seeds below {100 * args.collapse_below:.0f} % (the advisor's own level) in "
        "that arena. AfP effect: mean of the AfP point minus mean of its no-AfP control "
        "(ADDPG+AfP and ADDPG+AfDP vs ADDPG+AfD, ATD3+AfDP vs ATD3+AfD; same episodes, "
        "clip_actor_target and other settings; – where no such control was trained), "
        "percentage points, with its 95 % interval: [paired] over the "
        "seeds both evaluated where they share seeds (one seed: the same initial networks, "
        "environment stream and evaluation episodes), else [Welch 95 % interval]; both are in "
        "afp_study.json. Diverged seeds are left out of the means.",
        "",
    ]
    for episodes in sorted({r["episodes"] for r in stats}, reverse=True):
        sub = [r for r in stats if r["episodes"] == episodes]
        kept = sum(len(r["snapshot_seeds"]) for r in sub)
        lines += [
            f"## {episodes} training episodes",
            "",
            *(
                [
                    f"{kept} of {sum(len(r['seeds']) for r in sub)} agents here are actors "
                    f"kept at episode {episodes} of longer runs (`--snapshot-episodes`): what a "
                    f"run of {episodes} episodes ends with.",
                    "",
                ]
                if kept
                else []
            ),
            *common.markdown_table(
                (
                    "agent",
                    "mode",
                    "β",
                    "seeds",
                    "training",
                    "validation",
                    "collapsed (tr/val)",
                    "AfP effect, training",
                    "AfP effect, validation",
                    "per-seed training success",
                ),
                [
                    (
                        r["agent"],
                        _mode(r),
                        f"{r['beta']:g}" if r["afp"] else "–",
                        len(r["seeds"]),
                        _pct(r["training"]["mean"], r["training"]["ci95"]),
                        _pct(r["validation"]["mean"], r["validation"]["ci95"]),
                        f"{r['training']['collapsed']} / {r['validation']['collapsed']}",
                        _effect(r, "training"),
                        _effect(r, "validation"),
                        _per_seed(r["training"]["per_seed"]),
                    )
                    for r in sub
                ],
                align="llrrrrrrrl",
            ),
            "",
            "Diagnostics, mean over seeds of each agent's last training chunk (`metrics.npz` "
            "`log/...`): replaced fraction, mean ‖Eq. 2 step‖, rms ‖∇_aQ‖, mean Q(s, a_adv) − "
            "Q(s, Â), saturated heads; and the timeout share of the training-arena evaluation.",
            "",
            *common.markdown_table(
                ("agent", "mode", "β", *DIAGNOSTICS, "eval timeouts"),
                [
                    (
                        r["agent"],
                        _mode(r),
                        f"{r['beta']:g}" if r["afp"] else "–",
                        *(_num(r["diagnostics"][d]) for d in DIAGNOSTICS),
                        _num(r["timeout_training"]),
                    )
                    for r in sub
                ],
                align="lllr",
            ),
            "",
        ]
    other = {json.dumps(s, sort_keys=True) for s in settings.values()}
    lines += [
        "Settings besides the study's axes (preset, episodes, hyperparameters that differ "
        "from the preset): " + "; ".join(f"`{s}`" for s in sorted(other)) + ".",
        "",
        "![per-seed success vs β](afp_study.png)",
        "",
        f"Summary: `{summarize_cmd}`. Training commands, one per run directory (an "
        "`afp_study.py train` piece: `plan` with the same options lists the pieces):",
        "",
        *(f"- `{c}`" for c in where["commands"]),
    ]
    if notes:
        lines += ["", "Notes:", "", *(f"- {n}" for n in notes)]
    common.write_markdown(args.out / "afp_study.md", lines)
    from advisor_jax.fileio import atomic_write_json

    record = {
        "provenance": {
            "devices": sorted(where["devices"]),
            "dates": sorted(where["dates"]),
            "summarized": common.provenance(with_jax=False)["date"],
            "commands": where["commands"],
            "summarize": summarize_cmd,
            "collapse_below": args.collapse_below,
            "notes": notes,
        },
        "points": stats,
    }
    atomic_write_json(args.out / "afp_study.json", _json_safe(record))
    print(f"wrote {args.out / 'afp_study.json'} and {args.out / 'afp_study.png'}", file=sys.stderr)


def _json_safe(x):
    """NaN → None (strict JSON)."""
    if isinstance(x, dict):
        return {k: _json_safe(v) for k, v in x.items()}
    if isinstance(x, list | tuple):
        return [_json_safe(v) for v in x]
    if isinstance(x, float) and not math.isfinite(x):
        return None
    return x


# -- command line ---------------------------------------------------------------------------


def main() -> None:
    study = argparse.ArgumentParser(add_help=False)
    add = study.add_argument
    add("--preset", default="paper")
    add("--agents", nargs="+", default=list(AFP_AGENTS), help="AfP agent types")
    add("--controls", nargs="+", default=None, help="no-AfP controls (default: of --agents)")
    add("--betas", type=float, nargs="+", default=[0.01, 0.1, 1.0, 10.0])
    add("--modes", type=float, nargs="+", default=[0.0, 1.0], help="beta_normalize: 0, 1")
    add("--clip", type=float, nargs="+", default=[0.0], help="clip_actor_target: 0 (and 1)")
    add("--seeds", type=int, default=16)
    add("--seed", type=int, default=0, help="first seed")
    add("--episodes", type=int, nargs="+", default=[500, 200])
    add("--eval-episodes", type=int, default=100)
    add("--max-agents", type=int, nargs="+", default=[25], help="per piece; or per --episodes")
    add("--separate-episodes", action="store_true",
        help="train every --episodes budget apart (default: the smaller ones are snapshots "
             "of the longest runs' actors)")  # fmt: skip
    add("--hp", action="append", default=[], metavar="NAME=V", help="for every agent")

    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    sub = parser.add_subparsers(dest="command", required=True)
    p = sub.add_parser("plan", parents=[study], help="list the pieces and their device time")
    p.add_argument("--agent-steps-per-s", type=float, default=4856.0, help="H100, 64 agents")
    p.add_argument("--steps-per-episode", type=float, default=150.0)
    p.add_argument("--overhead-s", type=float, default=60.0, help="compile, evaluation, files")
    p.add_argument("--limit-s", type=float, default=600.0, help="one GPU command's limit")
    t = sub.add_parser("train", parents=[study], help="train pieces (default: all)")
    t.add_argument("--runs", type=Path, default=Path("runs/afp_study"))
    t.add_argument("--piece", nargs="+", default=[], help="piece numbers (plan) or run dir names")
    t.add_argument("--stop-after-s", type=float, default=0.0, help="see _Deadline; 0: never")
    t.add_argument("--checkpoint-every", type=int, default=0, help="chunks (0: at the end)")
    t.add_argument("--export", type=Path, default=None, help="small files to EXPORT/<run dir>/")
    t.add_argument("--progress", action="store_true")
    s = sub.add_parser("summarize", help="pool every finished run under --runs")
    s.add_argument(
        "--runs",
        type=Path,
        nargs="+",
        default=[Path("runs/afp_study")],
        help="folders of run directories (a seed found twice for a point: the first counts)",
    )
    s.add_argument("--out", type=Path, default=Path("results"))
    s.add_argument(
        "--collapse-below", type=float, default=common.ADVISOR_LEVEL, help="the advisor's success"
    )
    args = parser.parse_args()
    if args.command == "summarize":
        summarize(args)
        return
    _check_options(args)
    plan(args) if args.command == "plan" else train(args)


if __name__ == "__main__":
    main()
