"""How fast this CPU forgets the car runner's code and data: the evidence behind the verdict
of ``bench_runner.py`` (README, "What decides the verdict").

The back-to-back p99 of the control cycle depends on the machine as much as on the code.
Five probes show how, on the machine they run on:

1. **Forgetting curve.** After an idle gap (a busy-wait, or a sleep) time one call of: a
   200-element numpy add, the actor's 600×300 layer as one matvec (720 KB of weights), and
   the whole cycle (observation + MLP, as ``bench_runner.py`` times it), each call the
   repeat of an untimed one after the gap. Gaps and subjects interleave call by call, so
   that the machine's drift in speed falls on all alike.
2. **Code or data.** Back to back and after a 5 ms busy-wait, one numpy gather of a single
   element, of 176 elements on 176 different 4 KB pages (random order), and of 176 elements
   on 3 pages. If the cold cost does not grow with the pages and lines touched, it is not TLB
   misses or cache misses on the data (the loads are independent and overlap) but the serial
   path through numpy's and CPython's code and metadata.
3. **Timer ticks.** Back-to-back cycles with their start times folded modulo the guest
   kernel's tick period (1 / CONFIG_HZ): the share of the slowest 2 % that start in the
   densest sixteenth of the period, against the same for all cycles and for two periods
   that are not the tick's (uniform phases give about 1/16 plus sampling noise).
4. **Pinning.** Blocks of back-to-back cycles alternately on all CPUs and on each CPU
   alone (``os.sched_setaffinity``): moves between cores would show as a lower p99 pinned.
5. **Speed drift.** Chunks of back-to-back cycles alternating with chunks of a pure-Python
   loop (no numpy): the spread of the chunks' medians shows how the machine's speed
   changes over fractions of a second, for both alike.

The policy is the paper-size actor that ``bench_runner.py`` times (``car_subject.load_paper_actor``
exports it in a child process; the timed process never imports JAX). Writes a markdown report.

    python experiments/probe_cpu_caches.py [--rounds 300] [--out results/probe_cpu_caches.md]
"""

from __future__ import annotations

import os

os.environ.setdefault("OPENBLAS_NUM_THREADS", "1")  # as advisor-jax-car sets it, before numpy

import argparse  # noqa: E402
import gzip  # noqa: E402
import itertools  # noqa: E402
import platform  # noqa: E402
import time  # noqa: E402
from collections.abc import Callable  # noqa: E402

import numpy as np  # noqa: E402

from advisor_jax.bench import car_subject, measure, writing  # noqa: E402
from advisor_jax.runner.observation import ObservationBuilder, ObservationConfig  # noqa: E402

BUSY_GAPS_MS = (0.05, 0.1, 0.3, 1.0, 2.0, 5.0, 10.0)
SLEEP_GAPS_MS = (5.0, 50.0)
PAGE = 4096


def busy_wait(ms: float) -> None:
    """Spin in Python for ``ms`` milliseconds (the core stays busy, as between cycles of a
    loop that never sleeps)."""
    deadline = time.perf_counter_ns() + int(ms * 1e6)
    while time.perf_counter_ns() < deadline:
        pass


def kernel_hz() -> int | None:
    """CONFIG_HZ of the running Linux kernel, from /proc/config.gz or /boot/config-*."""
    candidates = ["/proc/config.gz", f"/boot/config-{platform.release()}"]
    for path in candidates:
        try:
            opener = gzip.open if path.endswith(".gz") else open
            with opener(path, "rt") as f:
                for line in f:
                    if line.startswith("CONFIG_HZ="):
                        return int(line.split("=", 1)[1])
        except (OSError, ValueError):
            continue
    return None


def after_gaps(
    subjects: dict[str, Callable[[], object]],
    gaps: dict[str, tuple[Callable[[], None], int]],
    seed: int = 0,
) -> dict[str, dict[str, np.ndarray]]:
    """µs per call of each subject after each gap: ``gaps`` maps a label to (wait, calls).

    Each timed call repeats an untimed call of the same subject after ``wait()``: the gap is
    the time since that exact work last ran. Rounds interleave everything, so that the
    machine's drift in speed (section 5) falls on all gaps alike: each round visits the gaps
    in a fresh random order, and for each gap the subjects in turn."""
    times = {label: {name: [] for name in subjects} for label in gaps}
    rng, ns = np.random.default_rng(seed), time.perf_counter_ns
    for r in range(max(calls for _, calls in gaps.values())):
        for label in rng.permutation([label for label, (_, calls) in gaps.items() if r < calls]):
            wait = gaps[label][0]
            for name, fn in subjects.items():
                fn()
                wait()
                t0 = ns()
                fn()
                times[label][name].append((ns() - t0) / 1e3)
    return {label: {n: np.array(t) for n, t in per.items()} for label, per in times.items()}


def cycle_subject(policy, scans: list, cfg: ObservationConfig) -> Callable[[], object]:
    """obs+mlp on the next scan and pose of a car swinging along x (as bench_runner.py)."""
    builder = ObservationBuilder(cfg, (2.0, 1.0))
    poses = car_subject.swinging_poses(4096)
    counter = itertools.count()

    def call():
        i = next(counter) % len(poses)
        if i == 0:
            builder.reset()  # the pose clock restarts: forget the previous pose
        return policy.act(builder.build(scans[i % len(scans)], poses[i]))

    return call


def gather_subjects() -> dict[str, Callable[[], object]]:
    rng = np.random.default_rng(0)
    buf = np.ones(2048 * PAGE, dtype=np.uint8)  # 8 MB, every page touched (faulted in)
    pages = np.arange(176) * PAGE + rng.integers(0, PAGE // 64, 176) * 64
    rng.shuffle(pages)
    lines = 1500 * PAGE + rng.permutation(176) * 64  # 176 lines on 3 pages
    one = pages[:1].copy()
    return {
        "1 element": lambda: buf.take(one),
        "176 elements on 176 pages": lambda: buf.take(pages),
        "176 elements on 3 pages": lambda: buf.take(lines),
    }


def densest_sixteenth(starts_ns: np.ndarray, period_ns: float) -> float:
    """Share of ``starts_ns`` in the most populated of 16 equal bins of the phase modulo
    ``period_ns``."""
    phase = np.mod(starts_ns, period_ns) / period_ns
    return float(np.bincount((phase * 16).astype(int).clip(0, 15), minlength=16).max()) / len(
        starts_ns
    )


def tick_phases(
    call: Callable[[], object], calls: int, warmup: int, hz: int
) -> tuple[list[tuple], int, float, float]:
    """Rows (period, ms, densest sixteenth of the slowest 2 %, of all cycles), then the
    number of slow cycles, the slow threshold (µs) and the median (µs)."""
    for _ in range(warmup):
        call()
    starts, took = np.empty(calls, dtype=np.int64), np.empty(calls)
    ns = time.perf_counter_ns
    for i in range(calls):
        t0 = ns()
        call()
        starts[i], took[i] = t0, (ns() - t0) / 1e3
    slow = took >= np.percentile(took, 98)
    tick = 1e9 / hz
    rows = []
    for label, period in [
        (f"tick, 1/{hz} s", tick),
        ("0.9 tick (control)", 0.9 * tick),
        ("1.1 tick (control)", 1.1 * tick),
    ]:
        rows.append(
            (
                label,
                period / 1e6,
                densest_sixteenth(starts[slow], period),
                densest_sixteenth(starts, period),
            )
        )
    return rows, int(slow.sum()), float(np.percentile(took, 98)), float(np.median(took))


def pinning(call: Callable[[], object], rounds: int, iters: int, warmup: int) -> list[tuple]:
    allowed = sorted(os.sched_getaffinity(0))
    modes = {"all CPUs " + ",".join(map(str, allowed)): set(allowed)}
    modes.update({f"CPU {c} only": {c} for c in allowed})
    blocks = {mode: [] for mode in modes}
    try:
        for _ in range(rounds):
            for mode, cpus in modes.items():
                os.sched_setaffinity(0, cpus)
                blocks[mode].append(
                    measure.per_call_us({"c": lambda i: call()}, iters, warmup)["c"]
                )
    finally:
        os.sched_setaffinity(0, allowed)
    rows = []
    for mode, bs in blocks.items():
        pooled = np.concatenate(bs)
        block_p99 = [np.percentile(b, 99) for b in bs]
        rows.append(
            (
                mode,
                len(pooled),
                *np.percentile(pooled, [50, 99]),
                f"{min(block_p99):.0f}–{max(block_p99):.0f}",
            )
        )
    return rows


def python_loop(values: list[float]) -> float:
    """200 float additions in pure Python (no numpy): the interpreter's own speed."""
    total = 0.0
    for v in values:
        total += v
    return total


def speed_drift(cycle: Callable[[], object], chunks: int, chunk_calls: int) -> list[tuple]:
    """Medians of alternating chunks of back-to-back calls, per subject: min, quartiles, max."""
    values = [float(v) for v in range(200)]
    subjects = {"obs+mlp": cycle, "pure-Python loop (200 additions)": lambda: python_loop(values)}
    medians = {name: [] for name in subjects}
    for _ in range(chunks):
        for name, fn in subjects.items():
            medians[name].append(
                np.median(measure.per_call_us({"c": lambda i, fn=fn: fn()}, chunk_calls, 50)["c"])
            )
    return [(name, *np.percentile(m, [0, 25, 50, 75, 100])) for name, m in medians.items()]


def pcts(t: np.ndarray) -> str:
    p50, p90 = np.percentile(t, [50, 90])
    return f"{p50:.1f} / {p90:.1f}"


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--rounds", type=int, default=300, help="timed calls per subject and gap")
    parser.add_argument(
        "--sleep-rounds", type=int, default=150, help="timed calls per subject after a sleep"
    )
    parser.add_argument("--tick-calls", type=int, default=20000, help="back-to-back cycles")
    parser.add_argument("--pin-rounds", type=int, default=4, help="blocks per pinning mode")
    parser.add_argument("--drift-chunks", type=int, default=40, help="chunks per drift subject")
    parser.add_argument("--out", default="results/probe_cpu_caches.md")
    args = parser.parse_args()
    if not hasattr(os, "sched_setaffinity"):
        parser.error("this probe needs Linux (CPU affinity, the kernel's CONFIG_HZ)")
    for name, least in (
        ("rounds", 20),
        ("sleep_rounds", 20),
        ("tick_calls", 1000),
        ("pin_rounds", 1),
        ("drift_chunks", 4),
    ):
        if getattr(args, name) < least:
            parser.error(f"--{name.replace('_', '-')} must be at least {least}")

    policy = car_subject.load_paper_actor()
    rng = np.random.default_rng(0)
    scans = [car_subject.synthetic_scan(rng, 0.0) for _ in range(64)]
    cfg = ObservationConfig(range_offset=policy.range_offset, bounds=policy.bounds)
    cycle = cycle_subject(policy, scans, cfg)
    probe = rng.random(200)
    big = max(policy.layers, key=lambda layer: layer.kernel.size)
    hidden = np.ones(big.kernel.shape[0], dtype=np.float32)
    subjects = {
        "add (200 float64)": lambda: probe + 1.0,
        f"matvec {big.kernel.shape[0]}×{big.kernel.shape[1]} "
        f"({big.kernel.nbytes / 1e3:.0f} KB)": lambda: hidden @ big.kernel,
        "obs+mlp": cycle,
    }

    print("1. forgetting curve (p50 / p90 µs)", flush=True)
    gaps = {"0 ms": ((lambda: None), args.rounds)}
    gaps.update(
        {f"busy-wait {g:g} ms": ((lambda g=g: busy_wait(g)), args.rounds) for g in BUSY_GAPS_MS}
    )
    gaps.update(
        {
            f"sleep {g:g} ms": ((lambda g=g: time.sleep(g / 1e3)), args.sleep_rounds)
            for g in SLEEP_GAPS_MS
        }
    )
    curve = []
    for label, times in after_gaps(subjects, gaps).items():
        curve.append((label, gaps[label][1], *(pcts(t) for t in times.values())))
        print("  {:18s} n {:4d}  ".format(*curve[-1][:2]) + "  ".join(curve[-1][2:]))

    print("2. code or data (p50 / p90 µs)", flush=True)
    gathers = gather_subjects()
    both = after_gaps(
        gathers,
        {"0 ms": ((lambda: None), args.rounds), "5 ms": ((lambda: busy_wait(5.0)), args.rounds)},
    )
    data_rows = [(name, pcts(both["0 ms"][name]), pcts(both["5 ms"][name])) for name in gathers]
    for row in data_rows:
        print("  {:28s} warm {}  after 5 ms {}".format(*row))

    hz = kernel_hz()
    tick_rows = None
    if hz:
        print("3. timer ticks", flush=True)
        tick_rows, n_slow, slow_from, median = tick_phases(cycle, args.tick_calls, 500, hz)
        for row in tick_rows:
            print("  {:20s} {:.3f} ms  slowest 2 %: {:.3f}  all: {:.3f}".format(*row))

    print("4. pinning", flush=True)
    pin_rows = pinning(cycle, args.pin_rounds, 4000, 500)
    for row in pin_rows:
        print("  {:16s} n {:6d}  p50 {:6.1f}  p99 {:6.1f}  block p99s {}".format(*row))

    print("5. speed drift (medians of 500-call chunks)", flush=True)
    drift_rows = speed_drift(cycle, args.drift_chunks, 500)
    for row in drift_rows:
        print(
            "  {:34s} min {:6.1f}  q1 {:6.1f}  median {:6.1f}  q3 {:6.1f}  max {:6.1f}".format(*row)
        )

    names = list(subjects)
    where = measure.provenance(with_jax=False)
    command = writing.command_line(
        "experiments/probe_cpu_caches.py", writing.changed_options(parser, args), scheduling=True
    )
    lines = [
        "# How fast this CPU forgets the control cycle's code and data",
        "",
        f"Date: {where['date']}. Machine: {where['cpu']}, {where['cpu_count']} cores "
        f"({measure.virtualisation()}), Linux {platform.release()} (CONFIG_HZ {hz or 'unknown'}), "
        f"Python {where['python']}, numpy {where['numpy']}, "
        f"OPENBLAS_NUM_THREADS={os.environ.get('OPENBLAS_NUM_THREADS')}.",
        "",
        f"Command: `{command}`",
        "",
        "Why the back-to-back p99 of `bench_runner.md` depends on the machine. Policy: the",
        "paper-size actor of `bench_runner.py`; cycle = observation from a 200-reading scan +",
        "MLP. All times are wall clock per call, in µs.",
        "",
        "## 1. Forgetting curve",
        "",
        "Each timed call repeats the same call, made untimed, after an idle gap: the gap is",
        "the time since that work last ran (0: back to back). Each round visits the gaps in a",
        "random order and, for each gap, the three subjects in turn, so that the machine's",
        "drift in speed (section 5) falls on all gaps alike. A busy-wait keeps the core in this",
        "process (a Python loop reading the clock); a sleep gives it up.",
        "",
        *writing.markdown_table(("gap", "calls", *(n + " p50 / p90" for n in names)), curve),
        "",
        "## 2. Code or data",
        "",
        "One numpy gather (`ndarray.take`) of an 8 MB buffer, warm (back to back) and after",
        "a 5 ms busy-wait. The gathers run the same code; they differ in the data pages and",
        "cache lines they touch.",
        "",
        *writing.markdown_table(("gather", "warm p50 / p90", "after 5 ms p50 / p90"), data_rows),
        "",
    ]
    if tick_rows:
        lines += [
            "## 3. Timer ticks",
            "",
            f"{args.tick_calls} back-to-back cycles (median {median:.1f} µs); the slowest 2 %",
            f"({n_slow} cycles, ≥ {slow_from:.1f} µs). Their start times folded modulo a",
            "period into 16 phase bins: the share in the most populated bin (uniform phases:",
            "about 0.06 plus sampling noise).",
            "",
            *writing.markdown_table(
                ("period", "ms", "densest 1/16, slowest 2 %", "densest 1/16, all cycles"),
                tick_rows,
                formats=("", ".3f", ".3f", ".3f"),
            ),
            "",
        ]
    lines += [
        "## 4. Pinning",
        "",
        f"Blocks of 4000 back-to-back cycles (after 500 warm-up calls), {args.pin_rounds} per",
        "mode, the modes alternating block by block.",
        "",
        *writing.markdown_table(
            ("CPUs", "calls", "p50", "p99", "block p99s"), pin_rows, ("", "", ".1f", ".1f", "")
        ),
        "",
        "## 5. Speed drift",
        "",
        f"{args.drift_chunks} chunks of 500 back-to-back calls per subject (after 50 warm-up",
        "calls each), the subjects alternating chunk by chunk: the spread of the chunk",
        "medians (µs).",
        "",
        *writing.markdown_table(
            ("subject", "min", "q1", "median", "q3", "max"), drift_rows, ("", ".1f")
        ),
        "",
    ]
    writing.write_markdown(args.out, lines)


if __name__ == "__main__":
    main()
