"""Plumbing shared by the scripts in experiments/: where a number was measured, how it was
timed, against which ceiling, and how it is written down.

One copy of each, so that every report is comparable with every other: the same fields say
where it ran, the same timer waits for JAX's asynchronous dispatch, the same kernels define
a ceiling, the same footer says how to run it again.

experiments/ is not a package: the scripts run as ``python experiments/NAME.py`` and find this
module through ``sys.path[0]`` (the script's own folder), from any working directory.

JAX is imported lazily and only where a function needs a device: ``bench_runner.py`` and
``probe_cpu_caches.py`` time the numpy-only car runner in a process that must never load it.
Their shared subject (the paper-size actor, synthetic scans, tracked poses) is at the end.
"""

from __future__ import annotations

import argparse
import datetime
import functools
import json
import math
import os
import platform
import shlex
import shutil
import subprocess
import sys
import tempfile
import time
from collections.abc import Callable, Iterable, Sequence
from pathlib import Path
from typing import Any

import numpy as np

from advisor_jax.fileio import atomic_write_text

# -- where a number was measured ------------------------------------------------------------


def cpu_name() -> str:
    """The CPU model ("Intel(R) Xeon(R) ..."): CPU-bound timings mean little without it."""
    try:
        with open("/proc/cpuinfo") as f:
            for line in f:
                if line.startswith("model name"):
                    return line.split(":", 1)[1].strip()
    except OSError:
        pass
    return platform.processor() or platform.machine()


def virtualisation() -> str:
    """ "KVM guest" and the like from lscpu's hypervisor line, "bare metal" when none: a VM's
    caches and speed are shared with its neighbours (bench_runner.md). Runs ``lscpu``, so it
    is not part of ``provenance()``."""
    try:
        out = subprocess.run(["lscpu"], capture_output=True, text=True, timeout=10).stdout
    except (OSError, subprocess.SubprocessError):
        return "unknown virtualisation"
    for line in out.splitlines():
        if line.startswith("Hypervisor vendor:"):
            return line.split(":", 1)[1].strip() + " guest"
    return "bare metal" if "cpu" in out.lower() else "unknown virtualisation"


def provenance(with_jax: bool = True) -> dict[str, Any]:
    """Where and when a number was measured: one dict for every report that records one.

    ``date`` is the day this runs (not the day the code was written). With ``with_jax``
    also JAX's first device: ``backend`` (its platform, "cpu"/"gpu"), ``device`` (its kind,
    "NVIDIA H100 80GB HBM3") and the JAX version; without, JAX is not imported (the car
    runner's benchmarks time a process that never loads it)."""
    record: dict[str, Any] = {
        "date": datetime.date.today().isoformat(),
        "host": platform.node(),
        "cpu": cpu_name(),
        "cpu_count": os.cpu_count(),
        "python": platform.python_version(),
        "numpy": np.__version__,
    }
    if with_jax:
        import jax

        device = jax.devices()[0]
        record.update(backend=device.platform, device=device.device_kind, jax=jax.__version__)
        if os.environ.get("XLA_FLAGS"):  # a number measured under other flags says so
            record["xla_flags"] = os.environ["XLA_FLAGS"]
    return record


# -- timers ---------------------------------------------------------------------------------


def _ready(out: Any) -> Any:
    """``out`` once computed: JAX dispatches asynchronously, so a timer that does not wait
    for the result times only the dispatch. Only when JAX is loaded: the car runner's
    benchmarks must not import it (and then nothing can be a JAX array)."""
    jax = sys.modules.get("jax")
    return out if jax is None else jax.block_until_ready(out)


def run_timed(fn: Callable[[], Any]) -> tuple[Any, float]:
    """``fn()``'s result (JAX arrays ready) and the wall-clock seconds it took."""
    t0 = time.perf_counter()
    out = _ready(fn())
    return out, time.perf_counter() - t0


def best_of(fn: Callable[[], Any], repeats: int) -> float:
    """Fastest of ``repeats`` calls of ``fn`` in seconds: the least disturbed by the machine.
    A ``fn`` whose inputs are donated must carry its state itself (e.g. in a closure)."""
    return min(run_timed(fn)[1] for _ in range(repeats))


def first_and_best(fn: Callable[[], Any], repeats: int) -> tuple[float, float]:
    """(seconds of the first call, which compiles; ``best_of`` the ``repeats`` after it)."""
    return run_timed(fn)[1], best_of(fn, repeats)


def per_call_us(
    cases: dict[str, Callable[[int], Any]],
    iters: int,
    warmup: int,
    pause: float = 0.0,
    before: Callable[[int], Any] | None = None,
) -> dict[str, np.ndarray]:
    """Wall-clock µs of every call of every case (each called with the call's index), the
    cases interleaved call by call: latency distributions (p50, p99), not a best time.
    ``pause`` (s): sleep before each round, as the car's control loop sleeps between cycles;
    ``before(i)``: an untimed call after the sleep (the loop's warm-up)."""
    for i in range(warmup):
        for fn in cases.values():
            fn(i)
    times = {name: np.empty(iters) for name in cases}
    wall_ns, sleep = time.perf_counter_ns, time.sleep
    for i in range(iters):
        if pause:
            sleep(pause)
        if before is not None:
            before(warmup + i)
        for name, fn in cases.items():
            t0 = wall_ns()
            fn(warmup + i)
            times[name][i] = (wall_ns() - t0) / 1e3
    return times


# -- ceilings: what the device can do at all, measured in the same process as the timings ---


def matmul_ceiling(n: int, repeats: int = 5, dtype: Any = "float32") -> float:
    """FLOP/s of an ``n``×``n`` matmul, fp32 at JAX's default precision (TF32 on recent
    NVIDIA GPUs) or ``dtype="bfloat16"``: the rate a dense network could reach on this
    device, this run."""
    import jax

    a = jax.random.normal(jax.random.PRNGKey(0), (n, n)).astype(dtype)
    matmul = jax.jit(lambda p, q: p @ q)
    return 2 * n**3 / first_and_best(lambda: matmul(a, a), repeats)[1]


def copy_ceiling(n_bytes: int, repeats: int = 5) -> float:
    """Bytes/s read plus written by a device-to-device copy of ``n_bytes`` of fp32: the
    best of a plain copy and an elementwise add (one read, one write each), since
    either can be the faster kernel. The data is random, not constant."""
    import jax

    x = jax.random.uniform(jax.random.PRNGKey(1), (n_bytes // 4,))
    kernels = (jax.jit(lambda a: a + 1.0), jax.jit(lambda a: a.copy()))
    seconds = min(first_and_best(functools.partial(f, x), repeats)[1] for f in kernels)
    return 2 * x.nbytes / seconds


# -- the numbers before a change, measured in the same command ------------------------------


def run_reference(tree: str | os.PathLike, script: str, argv: Sequence[str], report: str) -> dict:
    """The JSON report ``report`` of ``experiments/<script>`` of the checkout ``tree`` (e.g.
    the commit before a speed change: ``git worktree add /tmp/ref HEAD~1``, or on the device
    an untracked copy of it, which the ``run`` tool carries), run with ``argv`` and its own
    ``--out`` in a subprocess whose imports resolve to ``tree``: the previous numbers come
    from the same machine and the same minute as the new ones."""
    tree = Path(tree).resolve()  # the subprocess runs in tree/experiments: a relative tree breaks
    path = tree / "experiments" / script
    if not path.exists():
        raise SystemExit(f"--reference {tree}: no experiments/{script} there")
    here = Path(__file__).resolve().parents[1]
    paths = [p for p in os.environ.get("PYTHONPATH", "").split(os.pathsep) if p]
    paths = [str(tree)] + [p for p in paths if Path(p).resolve() != here]
    with tempfile.TemporaryDirectory() as out:
        subprocess.run(
            [sys.executable, str(path), *argv, "--out", out],
            check=True,
            env={**os.environ, "PYTHONPATH": os.pathsep.join(paths)},
            cwd=path.parent,
        )
        return json.loads((Path(out) / report).read_text())


# -- writing it down ------------------------------------------------------------------------


def markdown_table(
    header: Sequence[str],
    rows: Iterable[Sequence[Any]],
    formats: Sequence[str] = (),
    align: str = "lr",
) -> list[str]:
    """A markdown table as lines. ``formats``: a spec per column for ``format()`` (".1f",
    ",.0f"; "": ``str``); ``align``: "l" or "r" per column. In both the last entry stands for
    the columns after it: ``align="lr"`` is a label then numbers, ``formats=("", ".1f")`` a
    label then numbers to one decimal."""
    width = len(header)
    align = (align + align[-1] * width)[:width]
    specs = (*formats, *[formats[-1] if formats else ""] * width)[:width]
    lines = [
        "| " + " | ".join(header) + " |",
        "|" + "|".join("---:" if a == "r" else "---" for a in align) + "|",
    ]
    for row in rows:
        cells = (format(cell, spec) for cell, spec in zip(row, specs, strict=True))
        lines.append("| " + " | ".join(cells) + " |")
    return lines


def changed_options(
    parser: argparse.ArgumentParser, args: argparse.Namespace, skip: Iterable[str] = ("out",)
) -> list[str]:
    """The command-line options of ``args`` that differ from ``parser``'s defaults, as argv:
    a command line that reproduces the run without restating every default."""
    argv = []
    for key, value in vars(args).items():
        if key in skip or value == parser.get_default(key):
            continue
        flag = "--" + key.replace("_", "-")
        if value is True:
            argv.append(flag)
        elif isinstance(value, list | tuple):
            argv += [flag, *map(str, value)]
        else:
            argv += [flag, str(value)]
    return argv


def command_line(script: str, argv: Sequence[str], scheduling: bool = False) -> str:
    """``python SCRIPT ARGV...``, quoted for a shell, for a report's "Command:" line. With
    ``scheduling`` also the ``nice`` and ``taskset`` the process runs under (latency on a
    CPU depends on them)."""
    command = shlex.join(["python", script, *map(str, argv)])
    if scheduling:
        if os.nice(0) != 0:
            command = f"nice -n {os.nice(0)} {command}"
        cpus = sorted(os.sched_getaffinity(0))
        if len(cpus) < (os.cpu_count() or 0):
            command = f"taskset -c {','.join(map(str, cpus))} {command}"
    return command


def write_markdown(path: str | os.PathLike, lines: Sequence[str], echo: bool = False) -> None:
    """Writes ``lines`` as one markdown file ending in one newline, atomically (a reader never
    sees half a report), says where on stderr and, with ``echo``, prints it."""
    text = "\n".join(lines).rstrip("\n") + "\n"
    atomic_write_text(path, text)
    print(f"wrote {path}", file=sys.stderr)
    if echo:
        print(text, end="")


# -- populations trained with the tool (table1.py, afp_study.py) ----------------------------

ADVISOR_LEVEL = 0.5  # the advisor's own success (results/advisor.md): a seed below it collapsed

SMALL_RUN_FILES = ("run.json", "eval.json", "metrics.npz", "train_log.jsonl", "episodes.csv")
"""What a summary reads from a run directory: the files worth copying off a GPU machine
(never ``checkpoints/`` or ``params/``, which hold every agent's replay buffer and weights)."""


def export_small_files(run_dir: Path, dest: Path) -> None:
    """``SMALL_RUN_FILES`` of ``run_dir`` (those it has) into ``dest``."""
    dest.mkdir(parents=True, exist_ok=True)
    for name in SMALL_RUN_FILES:
        if (run_dir / name).is_file():
            shutil.copy2(run_dir / name, dest / name)


def hp_overrides(items: Sequence[str]) -> dict[str, float]:
    """``--hp NAME=V`` items as ``{name: value}``, one value each (several values are a
    grid, not a setting); unknown names and names given twice are refused."""
    from advisor_jax.training.population import parse_assignments

    parsed = parse_assignments(items, "--hp")
    several = [
        f"{name}={','.join(f'{v:g}' for v in values)}"
        for name, values in parsed.items()
        if len(values) != 1
    ]
    if several:
        raise ValueError(f"--hp takes one value per name, got {', '.join(several)}")
    return {name: values[0] for name, values in parsed.items()}


def run_status(run_dir: Path) -> str | None:
    """The ``status`` of ``run_dir/run.json`` ("finished", "interrupted", "running"), None
    when there is no run there yet."""
    run_file = Path(run_dir) / "run.json"
    if not run_file.is_file():
        return None
    return json.loads(run_file.read_text()).get("status", "running")


def train_or_resume(run_dir: Path, cfg, hp, grid, seeds, **kwargs) -> str:
    """Trains one population into ``run_dir`` (``run_training``'s keywords pass through):
    not at all when it finished there, resumed (``resume=True``) when a run was started
    there and stopped, afresh otherwise. Returns "finished", "resumed" or "trained"."""
    status = run_status(run_dir)
    if status == "finished":
        return "finished"
    from advisor_jax.training.host_loop import run_training

    run_training(cfg, hp, grid, seeds, run_dir, resume=status is not None, **kwargs)
    return "trained" if status is None else "resumed"


def finished_runs(root: Path) -> tuple[list[tuple[Path, dict]], list[str]]:
    """Every run directory below ``root`` (one holding run.json) whose run finished, sorted
    by path, with its run.json; and a note for each one that did not finish."""
    runs, notes = [], []
    for run_file in sorted(Path(root).rglob("run.json")):
        summary = json.loads(run_file.read_text())
        if summary.get("status") == "finished":
            runs.append((run_file.parent, summary))
        else:
            notes.append(f"{run_file.parent}: status {summary.get('status')!r}, left out")
    return runs, notes


AGENT_FIELDS = ("actor_hidden", "critic_state_hidden", "critic_hidden", "buffer_size",
                "batch_size", "policy_delay", "learning_starts", "precision")  # fmt: skip
STATIC_SETTINGS = (*AGENT_FIELDS, "arena", "envs_per_agent", "updates_per_step",
                   "max_episode_steps")  # fmt: skip
"""The static settings (AgentConfig, TrainConfig) that change what an agent learns, named
by ``preset_differences`` where a run differs from its preset."""


def setting_text(value) -> str:
    """One setting's value as the reports print it: ``4e-05``, ``2``, ``bf16``, ``64x64``."""
    if isinstance(value, (list, tuple)):
        return "x".join(map(str, value))
    return f"{value:g}" if isinstance(value, (int, float)) else str(value)


def preset_setting(preset_name: str, agent: str, name: str):
    """A preset's value of a hyperparameter or of a static setting (``STATIC_SETTINGS``)."""
    from advisor_jax.agent.config import preset
    from advisor_jax.agent.settings import flat_items

    static, hp = preset(preset_name, agent)
    if name in AGENT_FIELDS:
        return getattr(static.agent, name)
    return getattr(static, name) if name in STATIC_SETTINGS else flat_items(hp)[name]


def preset_differences(summary: dict, agent_row: dict) -> dict[str, Any]:
    """The settings of one agent of a run: its preset, its training episodes and the
    hyperparameters and static settings (``STATIC_SETTINGS``: ``policy_delay``,
    ``precision``, ...) in which it differs from that preset's defaults. A run.json
    without a ``preset`` was trained from ``paper``; one without a hyperparameter was
    trained before it existed, so with what its declared default (the paper's value, a
    switch off) means, whatever the preset says today."""
    from advisor_jax.agent.config import default_hparams, preset
    from advisor_jax.agent.settings import flat_items

    name = summary.get("preset", "paper")
    static, defaults = preset(name, summary["agent"])
    before, defaults = flat_items(default_hparams(static.agent)), flat_items(defaults)
    settings: dict[str, Any] = {"preset": name, "episodes": summary["config"]["episodes"]}
    for field, default in defaults.items():
        value = agent_row.get(field, before[field])
        if not math.isclose(value, default, rel_tol=1e-6):
            settings[field] = value
    # static settings (one compile each: --policy-delay, --batch-size, --precision, ...)
    # recorded in run.json's config; a field an older run.json lacks is left unnamed
    recorded = summary["config"]
    for field in STATIC_SETTINGS:
        if field in AGENT_FIELDS:
            value, default = recorded.get("agent", {}).get(field), getattr(static.agent, field)
        else:
            value, default = recorded.get(field), getattr(static, field)
        value = tuple(value) if isinstance(value, list) else value
        if value is not None and value != default:
            settings[field] = value
    return settings


def seeds_with_ci(
    ax, x: float, values: Sequence[float], color, label=None, log_x=False, width: float = 0.15
) -> None:
    """One group's per-seed values as jittered dots around ``x`` (spread ``width``, a
    factor of 10**width on a log axis) and its mean with the Student-t 95 % interval."""
    from advisor_jax.training.reporting import mean_ci95

    v = np.asarray([u for u in values if u is not None and np.isfinite(u)], np.float64)
    if v.size == 0:
        return
    jitter = np.random.default_rng(v.size).uniform(-width / 2, width / 2, v.size)
    xs = x * 10.0**jitter if log_x else x + jitter
    ax.scatter(xs, v, s=10, color=color, alpha=0.45, linewidths=0)
    mean, half = mean_ci95(v)
    ax.errorbar(
        x,
        mean,
        yerr=0.0 if math.isnan(half) else half,
        fmt="o",
        ms=5,
        capsize=4,
        color=color,
        markeredgecolor="black",
        label=label,
    )


# -- the car runner's subject (bench_runner.py, probe_cpu_caches.py) ------------------------

PAPER_ACTOR_HIDDEN = (600, 300)


def export_paper_actor(out_dir: str) -> None:
    """A freshly initialised paper-size actor (20→600→300→2), exported as the car loads it."""
    import jax

    import envs
    from advisor_jax.agent.networks import init_actor, make_actor
    from advisor_jax.deploy.export import export_policy

    params = init_actor(make_actor(PAPER_ACTOR_HIDDEN), jax.random.key(0))
    rng = np.random.default_rng(1)
    golden = rng.uniform(0.0, 1.0, (64, 20)).astype(np.float32)
    export_policy(
        params,
        out_dir,
        actor_hidden=PAPER_ACTOR_HIDDEN,
        env_meta=envs.make_env("physical").metadata(),  # the arena the car's policy trains in
        config_meta={"preset": "paper", "agent": "ATD3+AfDP"},
        golden_obs=golden,
    )


def load_paper_actor():
    """The paper-size actor, exported in a child process (``python common.py export DIR``:
    JAX never enters this one) and loaded and verified as the car loads it."""
    from advisor_jax.runner.policy import load_policy

    with tempfile.TemporaryDirectory() as tmp:
        subprocess.run([sys.executable, __file__, "export", tmp], check=True)
        policy = load_policy(tmp)
    assert "jax" not in sys.modules
    return policy


def synthetic_scan(rng: np.random.Generator, stamp: float):
    """200 readings over one turn, ~5 % invalid (0 mm), at the resolution the ``rplidar``
    package reports: angle in 1/64 degree (clockwise), distance in 1/4 mm."""
    from advisor_jax.runner.observation import Scan

    angles = np.floor(((np.arange(200) * 1.8 + rng.uniform(0.0, 1.8, 200)) % 360.0) * 64) / 64
    dist = np.floor(rng.uniform(150.0, 6000.0, 200) * 4) / 4
    dist[rng.random(200) < 0.05] = 0.0
    quality = np.full(200, 15.0)
    return Scan(np.stack([quality, angles, dist], axis=1), stamp)


def swinging_poses(n: int) -> list:
    """Tracked poses of a car swinging along x at up to 0.5 m/s, 20 Hz. Made up front: the
    tracker thread builds each Pose when it arrives, outside the control cycle."""
    from advisor_jax.runner.observation import Pose

    return [Pose(math.sin(0.05 * i), 0.1, 0.2, 0.05 * i, 0.0) for i in range(n)]


if __name__ == "__main__":  # the child process of load_paper_actor
    if len(sys.argv) != 3 or sys.argv[1] != "export":
        sys.exit("usage: python experiments/common.py export DIR  (used by load_paper_actor)")
    export_paper_actor(sys.argv[2])
