"""Latency of the car runner's control cycle on this CPU (paper §5.2: the actor runs on board).

Measures, per call, after a warm-up (time.perf_counter_ns around each call):

* ``obs``: observation from a 200-reading RPLIDAR scan (16 zones) + pose + goal;
* ``mlp``: ``Policy.act`` on one observation at the paper's actor size 20→600→300→2;
* ``obs+mlp``: both, i.e. the per-cycle compute the brief targets (p99 ≤ 0.2 ms);
* ``cycle``: ``Controller.cycle`` = watchdog + obs + mlp + Ackermann conversion.

The policy is a freshly initialised paper-size actor exported with ``advisor_jax.export``
in a child process (so this script needs JAX, but the timed process never imports it).
Writes a markdown table.

    python experiments/bench_runner.py [--iters 20000] [--out results/bench_runner.md]
"""

from __future__ import annotations

import os

os.environ.setdefault("OPENBLAS_NUM_THREADS", "1")  # as advisor-jax-car sets it, before numpy

import argparse  # noqa: E402
import platform  # noqa: E402
import subprocess  # noqa: E402
import sys  # noqa: E402
import tempfile  # noqa: E402
import time  # noqa: E402
import timeit  # noqa: E402
import types  # noqa: E402

import numpy as np  # noqa: E402

from advisor_jax.runner.drive import AckermannDrive  # noqa: E402
from advisor_jax.runner.loop import Controller, LoopConfig  # noqa: E402
from advisor_jax.runner.observation import (  # noqa: E402
    ObservationBuilder,
    ObservationConfig,
    Pose,
    Scan,
    rplidar_zones,
    scan_to_robot_frame,
)
from advisor_jax.runner.policy import load_policy  # noqa: E402
from advisor_jax.runner.zones import reduce_to_zones  # noqa: E402

DATE = "2026-11-22"
ENV_META = {
    "arena": "physical",
    "dt": 0.05,
    "v_max": 1.0,
    "omega_max": 1.0,
    "max_range": 1.0,
    "robot_radius": 0.22,
    "lidar_range_offset": 0.22,
    "h_max": 150,
    "T_g": 0.15,
    "T_c": 0.1,
    "bounds": [-2.45, 2.45, -1.5, 1.5],
}


def export_paper_actor(out_dir: str) -> None:
    import jax

    from advisor_jax.export import export_policy
    from advisor_jax.networks import Actor, init_actor

    hidden = (600, 300)
    params = init_actor(Actor(hidden), jax.random.key(0))
    rng = np.random.default_rng(1)
    golden = rng.uniform(0.0, 1.0, (64, 20)).astype(np.float32)
    export_policy(
        params,
        out_dir,
        actor_hidden=hidden,
        env_meta=ENV_META,
        config_meta={"preset": "paper", "agent": "ATD3+AfDP"},
        golden_obs=golden,
    )


def synthetic_scan(rng: np.random.Generator, stamp: float) -> Scan:
    """200 readings over one turn (clockwise degrees, mm), ~5 % invalid (0 mm)."""
    angles = (np.arange(200) * 1.8 + rng.uniform(0.0, 1.8, 200)) % 360.0
    dist = rng.uniform(150.0, 6000.0, 200)
    dist[rng.random(200) < 0.05] = 0.0
    quality = np.full(200, 15.0)
    return Scan(np.stack([quality, angles, dist], axis=1), stamp)


def timed(cases: dict, iters: int, warmup: int) -> dict[str, tuple[np.ndarray, np.ndarray]]:
    """Per-call (wall-clock, thread CPU) times in µs of every case, interleaved call by call
    so that all cases see the same background load. CPU time leaves out the time other
    processes held the core, which on a shared machine dominates the wall-clock tail."""
    for i in range(warmup):
        for fn in cases.values():
            fn(i)
    wall = {name: np.empty(iters) for name in cases}
    cpu = {name: np.empty(iters) for name in cases}
    wall_ns, cpu_ns = time.perf_counter_ns, time.thread_time_ns
    for i in range(iters):
        for name, fn in cases.items():
            c0, t0 = cpu_ns(), wall_ns()
            fn(warmup + i)
            t1, c1 = wall_ns(), cpu_ns()
            wall[name][i], cpu[name][i] = (t1 - t0) / 1e3, (c1 - c0) / 1e3
    return {name: (wall[name], cpu[name]) for name in cases}


def cpu_name() -> str:
    try:
        with open("/proc/cpuinfo") as f:
            for line in f:
                if line.startswith("model name"):
                    return line.split(":", 1)[1].strip()
    except OSError:
        pass
    return platform.processor() or platform.machine()


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--iters", type=int, default=20000)
    parser.add_argument("--warmup", type=int, default=2000)
    parser.add_argument("--out", default="results/bench_runner.md")
    parser.add_argument("--export-only", metavar="DIR", help=argparse.SUPPRESS)
    args = parser.parse_args()
    if args.export_only:
        export_paper_actor(args.export_only)
        return

    with tempfile.TemporaryDirectory() as tmp:
        subprocess.run([sys.executable, __file__, "--export-only", tmp], check=True)
        policy = load_policy(tmp)
    assert "jax" not in sys.modules
    rng = np.random.default_rng(0)
    scans = [synthetic_scan(rng, 0.0) for _ in range(64)]
    cfg = ObservationConfig(range_offset=policy.range_offset, bounds=policy.bounds)
    builder = ObservationBuilder(cfg, (2.0, 1.0))  # for obs0 only
    controller = Controller(
        policy,
        ObservationBuilder(cfg, (2.0, 1.0)),
        AckermannDrive(0.26, 0.4),
        LoopConfig(max_scan_age=1e9, max_pose_age=1e9),
    )

    def pose(i: int) -> Pose:  # a car swinging along x at up to 0.5 m/s, 20 Hz
        return Pose(np.sin(0.05 * i), 0.1, 0.2, 0.05 * i, 0.0)

    obs0 = builder.build(scans[0], pose(0))
    # Each case gets its own builder so that every one sees a smoothly moving pose.
    builders = [ObservationBuilder(cfg, (2.0, 1.0)) for _ in range(2)]
    beams = [scan_to_robot_frame(s.points) + (s.points[:, 2] > 0,) for s in scans]
    generic_np = types.SimpleNamespace(**{k: getattr(np, k) for k in dir(np) if k[0] != "_"})
    cases = {
        "obs (200-point scan → 20-d)": lambda i: builders[0].build(scans[i % 64], pose(i)),
        "mlp (20→600→300→2)": lambda i: policy.act(obs0),
        "obs+mlp": lambda i: policy.act(builders[1].build(scans[i % 64], pose(i))),
        "cycle (watchdog+obs+mlp+drive)": lambda i: controller.cycle(0.0, scans[i % 64], pose(i)),
        "zones only: car path (rplidar_zones)": lambda i: rplidar_zones(
            scans[i % 64].points, beams[i % 64][2], range_offset=0.22
        ),
        "zones only: generic [200, 16] path": lambda i: reduce_to_zones(
            *beams[i % 64], range_offset=0.22, xp=generic_np
        ),
    }
    load_before = os.getloadavg()[0]
    rows = []
    for name, (wall, cpu) in timed(cases, args.iters, args.warmup).items():
        row = (
            name,
            *np.percentile(wall, [50, 99]),
            wall.mean(),
            wall.max(),
            *np.percentile(cpu, [50, 99]),
        )
        rows.append(row)
        print(
            "{:32s} wall p50 {:6.1f} p99 {:7.1f} mean {:6.1f} max {:8.1f} | "
            "cpu p50 {:6.1f} p99 {:6.1f} µs".format(*row)
        )
    # The same MLP call back to back: its 770 KB of weights stay in this core's L2.
    for name, (wall, cpu) in timed(
        {"mlp, back to back (warm L2)": lambda i: policy.act(obs0)}, args.iters, args.warmup
    ).items():
        rows.append((name, *np.percentile(wall, [50, 99]), wall.mean(), wall.max(),
                     *np.percentile(cpu, [50, 99])))  # fmt: skip
        print("{:32s} wall p50 {:6.1f} p99 {:7.1f}".format(*rows[-1][:3]))
    load_after = os.getloadavg()[0]
    probe = np.random.default_rng(0).random(200)
    add_us = min(timeit.repeat(lambda: probe + 1.0, number=2000, repeat=20)) / 2000 * 1e6

    target = rows[2]
    wall_ok, cpu_ok = target[2] <= 200.0, target[6] <= 200.0
    threads = {k: os.environ.get(k) for k in ("OMP_NUM_THREADS", "OPENBLAS_NUM_THREADS")}
    command = "python experiments/bench_runner.py" + "".join(
        f" --{k} {v}"
        for k, v in (("iters", args.iters), ("warmup", args.warmup))
        if v != parser.get_default(k)
    )
    if os.nice(0) != 0:
        command = f"nice -n {os.nice(0)} {command}"
    lines = [
        "# Runner latency (numpy-only car runner)",
        "",
        f"Date: {DATE}. Machine: {cpu_name()}, {os.cpu_count()} cores, Linux, Python "
        f"{platform.python_version()}, numpy {np.__version__} (OpenBLAS), BLAS threads env "
        f"{threads} (advisor-jax-car sets OPENBLAS_NUM_THREADS=1 the same way).",
        f"Load average (1 min) before/after: {load_before:.1f} / {load_after:.1f} on "
        f"{os.cpu_count()} cores. Speed probe: one numpy "
        f"add of 200 float64 took {add_us:.2f} µs (best of 20 x 2000) right after the run.",
        f"Iterations: {args.iters} per row after {args.warmup} warm-up, one call each, the "
        "rows interleaved call by call (same background load for all); garbage "
        "collector on.",
        "",
        f"Command: `{command}`",
        "",
        "| step | wall p50 (µs) | wall p99 (µs) | wall mean (µs) | wall max (µs) "
        "| CPU p50 (µs) | CPU p99 (µs) |",
        "| --- | ---: | ---: | ---: | ---: | ---: | ---: |",
        *("| {} | {:.1f} | {:.1f} | {:.1f} | {:.1f} | {:.1f} | {:.1f} |".format(*r) for r in rows),
        "",
        f"Target p99 ≤ 200 µs per cycle (obs+mlp): wall-clock {target[2]:.1f} µs "
        f"(**{'met' if wall_ok else 'missed'}**), thread CPU time {target[6]:.1f} µs "
        f"(**{'met' if cpu_ok else 'missed'}**).",
        "",
        "Wall = `time.perf_counter_ns` around each call; CPU = `time.thread_time_ns`, which",
        "leaves out the time the scheduler gave the core to other processes. On a loaded",
        "shared machine the wall-clock tail (p99, max) is preemption by those processes, not",
        "the runner's work; on the car the runner owns its core.",
        "",
        "Scan: 200 readings over one turn (clockwise degrees, mm, ~5 % invalid), as the",
        "RPLIDAR thread hands them over (a float64 [200, 3] array). Policy: a freshly",
        "initialised paper-size actor (193,502 parameters), float32, loaded and verified with",
        "`load_policy` in a process that never imports JAX. `cycle` adds the watchdog checks",
        "and the Ackermann conversion. The zone rows time the reduction alone: the car's",
        "`rplidar_zones` (a scatter-minimum straight from the RPLIDAR points) against",
        "`zones.reduce_to_zones`' generic [beams, 16] membership-matrix path (the one the",
        "simulator runs under jax.numpy) on the same scans; their outputs are bit-identical",
        "(tests/runner). Because the rows are interleaved, each `mlp` call finds the actor's",
        "770 KB of float32 weights partly evicted from the core's L2 by the other rows, as in",
        "the car loop, where the cycle runs once per 50 ms between other threads; the last",
        "row runs the MLP back to back, weights warm in L2, for comparison.",
        "",
    ]
    os.makedirs(os.path.dirname(args.out) or ".", exist_ok=True)
    with open(args.out, "w", encoding="utf-8") as f:
        f.write("\n".join(lines))
    print(f"wrote {args.out}", file=sys.stderr)


if __name__ == "__main__":
    main()
