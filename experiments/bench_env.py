"""Benchmark: navigation-env steps per second versus the number of parallel envs.

Measures ``jax.jit`` of a ``lax.scan`` over ``--steps`` calls of ``jax.vmap(env.step)``
(MJX sensors, reward, termination and auto-reset included), each env driving a fixed
random action drawn once per env (so robots collide, time out and reset as in training),
for each motion model of ``--motions`` (``kinematic``: a unicycle; ``mjx``: the P3DX body
stepped by ``mjx.step``, envs/motion.py): a row per model and size.
Optionally (``--breakdown``) the same scan over the parts of a step: the MJX sensor pass
alone, the ``qvel`` + ``mjx.step`` alternative, ``reset`` alone and, for ``mjx``, the
drive alone; (``--ceiling``) the device's copy bandwidth and fp32 matmul rate, against
which the env's bytes and FLOPs per step are compared; (``--check``) the device's MJX
readings against CPU MuJoCo.

    python experiments/bench_env.py --motions kinematic mjx --envs 64 256 1024 --breakdown --check
    python experiments/bench_env.py --motions kinematic mjx --envs 32768 131072 --check --append

Writes ``<out>.md`` (tables) and ``<out>.json`` (all numbers, device, command, date).
"""

from __future__ import annotations

import dataclasses
import functools
import json
import pathlib
import re
import sys

import jax
import jax.numpy as jnp
import numpy as np
import tyro

import envs
from advisor_jax.bench import measure, writing
from advisor_jax.fileio import atomic_write_json, atomic_write_text


@dataclasses.dataclass(frozen=True)
class Args:
    arena: str = "training"
    """Arena to step (see ``advisor-jax arena --help``)."""
    motions: tuple[str, ...] = ("kinematic",)
    """Motion models to measure, one row each (kinematic, mjx or mjx:KEY=VALUE,...)."""
    envs: tuple[int, ...] = (64, 256, 1024, 4096)
    """Numbers of parallel environments to measure."""
    steps: int = 100
    """Env steps per jitted scan (one timed call)."""
    repeats: int = 3
    """Timed calls per size; the best is reported."""
    breakdown: bool = False
    """Also time the sensor pass alone and reset alone, at the largest size."""
    ceiling: bool = False
    """Also measure copy bandwidth and fp32 matmul rate of the device."""
    check: bool = False
    """Also check the device's MJX readings against CPU MuJoCo at 100 random poses."""
    dump_hlo: bool = False
    """Also write the optimised HLO of one vmapped step at the largest size (<out>_hlo.txt)."""
    append: bool = False
    """Keep the runs already in <out>.json and add this one (e.g. CPU, then GPU)."""
    out: str = "results/bench_env"
    """Output path without extension: writes .md and .json."""
    date: str = ""
    """Date to record (default: today)."""


def _cost(fn, *args) -> dict:
    """XLA's own count of FLOPs and bytes accessed of a compiled function, and the bytes
    its top-level kernels read and write (see ``kernel_io_bytes``)."""
    try:
        compiled = fn.lower(*args).compile()
        cost = compiled.cost_analysis()
        cost = cost[0] if isinstance(cost, list | tuple) else cost
        return {
            "flops": float(cost.get("flops", 0.0)),
            "bytes": float(cost.get("bytes accessed", 0.0)),
            "kernel_io": kernel_io_bytes(compiled.as_text()),
        }
    except Exception as err:  # cost analysis is best effort; the timing is the result
        nan = float("nan")
        return {"flops": nan, "bytes": nan, "kernel_io": nan, "error": str(err)}


_SHAPE = re.compile(r"(pred|[fsu]\d+)\[([\d,]*)\]")
_INSTR = re.compile(r"\s*(?:ROOT )?%(\S+) = (.*?) ([\w-]+)\((.*)")
_NO_KERNEL = ("parameter", "get-tuple-element", "tuple", "constant", "bitcast")


def _nbytes(shape: str) -> int:
    total = 0
    for dtype, dims in _SHAPE.findall(shape.split("{")[0] if shape[0] != "(" else shape):
        size = int(np.prod([int(d) for d in dims.split(",") if d]))
        total += size * (1 if dtype == "pred" else int(dtype[1:]) // 8)
    return total


def kernel_io_bytes(hlo: str) -> float:
    """Bytes read plus written by the top-level kernels of an optimised HLO module: every
    fused kernel reads its operands from and writes its results to device memory (an
    upper bound on DRAM traffic: L2 may catch some of it; a lower one on what XLA's
    ``bytes accessed`` counts, which includes traffic inside fused kernels)."""
    entry = hlo[hlo.index("\nENTRY") :]
    entry = entry[: entry.index("\n}\n")]
    sizes, total = {}, 0
    for line in entry.splitlines()[1:]:
        match = _INSTR.match(line)
        if not match:
            continue
        name, shape, op, rest = match.groups()
        sizes[name] = _nbytes(shape)
        if op not in _NO_KERNEL:
            operands = re.findall(r"%([\w.\-]+)", rest.split("),")[0])
            total += sizes[name] + sum(sizes.get(o, 0) for o in operands)
    return float(total)


def bench_step(env, n: int, steps: int, repeats: int) -> dict:
    key_reset, key_action = jax.random.split(jax.random.PRNGKey(0))
    state = jax.jit(jax.vmap(env.reset))(jax.random.split(key_reset, n))
    low, high = jnp.array([0.0, -1.0]), jnp.array([1.0, 1.0])
    action = jax.random.uniform(key_action, (n, 2), minval=low, maxval=high)
    step = jax.vmap(env.step)

    @jax.jit
    def run(state, action):
        def body(s, _):
            s = step(s, action)
            return s, s.done

        state, done = jax.lax.scan(body, state, None, length=steps)
        return state, jnp.mean(done)

    first, best = measure.first_and_best(lambda: run(state, action), repeats)
    _, done_rate = run(state, action)
    per_env_state = sum(x.nbytes for x in jax.tree_util.tree_leaves(state)) / n
    cost = _cost(jax.jit(step), state, action)  # one step: XLA counts a scan body once
    return {
        "envs": n,
        "steps_per_s": n * steps / best,
        "seconds": best,
        "compile_s": first - best,
        "done_per_step": float(done_rate),
        "state_bytes_per_env": per_env_state,
        # A step reads and writes the state and reads the action: the minimum traffic.
        "min_bytes_per_step": 2 * per_env_state + 8,
        "xla_flops_per_step": cost["flops"] / n,
        "xla_bytes_per_step": cost["bytes"] / n,
        "kernel_io_bytes_per_step": cost["kernel_io"] / n,
    }


def bench_parts(env, n: int, steps: int, repeats: int) -> dict:
    """Parts of a step, each in the same scan shape as the step: the sensor pass the env
    uses (pose written to qpos, ``mjx.kinematics`` + ``mjx.sensor_pos``), the alternative
    of our first design (joint velocities, then a full ``mjx.step``), ``reset`` alone and,
    under the ``mjx`` motion model, its drive alone (``substeps`` × ``mjx.step``)."""
    from envs.mjcf import mjx

    state = jax.jit(jax.vmap(env.reset))(jax.random.split(jax.random.PRNGKey(0), n))
    proximity = jax.vmap(env.proximity)
    reset = jax.vmap(env.reset)
    model, data0 = env.sensors.model, env.sensors.data

    def physics_step(pose):  # qvel = (V cos θ, V sin θ, ω), then mjx.step (Euler)
        qvel = jnp.stack([jnp.cos(pose[2]), jnp.sin(pose[2]), jnp.float32(0.5)])
        with jax.default_matmul_precision("highest"):
            d = mjx.step(model, data0.replace(qpos=pose, qvel=qvel))
        return d.qpos, d.sensordata

    physics = jax.vmap(physics_step)

    @jax.jit
    def mjx_steps(pose):
        def body(p, _):
            q, readings = physics(p)
            return q.at[:, 0].add(1e-4 * readings[:, 0]), ()

        return jax.lax.scan(body, pose, None, length=steps)[0]

    @jax.jit
    def sensors(pose, layout):
        def body(p, _):
            prox = proximity(p, layout)
            return p.at[:, 0].add(1e-4 * prox[:, 0]), ()

        return jax.lax.scan(body, pose, None, length=steps)[0]

    @jax.jit
    def resets(key):
        def body(k, _):
            s = reset(k)
            return s.key, jnp.sum(s.obs)

        return jax.lax.scan(body, key, None, length=steps)[1]

    parts = [
        ("sensors (kinematics + sensor_pos)", sensors, (state.pose, state.layout)),
        ("mjx.step with qvel (not used)", mjx_steps, (state.pose,)),
        ("reset", resets, (state.key,)),
    ]
    if env.drive is not None:
        move = jax.vmap(env.drive.move)
        v, w = jnp.full(n, 0.8), jnp.linspace(-4.0, 4.0, n)

        @jax.jit
        def drives(pose, qvel):
            def body(carry, _):
                pose, _, qvel = move(*carry, v, w)
                return (pose, qvel), ()

            return jax.lax.scan(body, (pose, qvel), None, length=steps)[0]

        parts.append(
            (f"drive ({env.drive.params.substeps} × mjx.step)", drives, (state.pose, state.qvel))
        )
    out = {}
    for name, fn, args in parts:
        if "not used" in name and env.procedural:
            continue  # needs the per-env model; the fixed-arena comparison suffices
        _, best = measure.first_and_best(functools.partial(fn, *args), repeats)
        out[name] = {"steps_per_s": n * steps / best, "seconds": best}
    return out


def check_parity(env, poses: int = 100) -> float:
    """Largest |MJX on this device − CPU MuJoCo| over random collision-free poses."""
    import mujoco

    key = jax.random.PRNGKey(7)
    starts = jax.jit(jax.vmap(env.reset))(jax.random.split(key, poses))
    layout = np.asarray(starts.layout)
    mjx_raw = np.asarray(jax.jit(jax.vmap(env.sensor_readings))(starts.pose, starts.layout))
    worst = 0.0
    for i in range(poses):
        model = env.mj_model
        if env.procedural:
            model = mujoco.MjModel.from_xml_string(env.xml(layout[i]))
        data = mujoco.MjData(model)
        data.qpos[:] = np.asarray(starts.pose[i], np.float64)
        mujoco.mj_forward(model, data)
        worst = max(worst, float(np.max(np.abs(mjx_raw[i] - data.sensordata))))
    return worst


def main(args: Args) -> dict:
    models = [envs.make_env(args.arena, motion=m) for m in args.motions]
    where = measure.provenance()
    result = {
        **where,
        "arena": args.arena,
        "device": f"{where['backend']}: {where['device']}",  # the format of the runs recorded
        "date": args.date or where["date"],
        "command": writing.command_line("experiments/bench_env.py", sys.argv[1:]),
        "steps_per_scan": args.steps,
        "rows": [],
    }
    for env in models:
        motion = env.config.motion_setting
        for n in args.envs:
            row = {"motion": motion, **bench_step(env, n, args.steps, args.repeats)}
            print(
                f"{motion:>10} {n:>8} envs  {row['steps_per_s'] / 1e6:9.3f} M steps/s  "
                f"(compile {row['compile_s']:.1f} s, done/step {row['done_per_step']:.4f})",
                flush=True,
            )
            result["rows"].append(row)
        if args.check:
            result.setdefault("parity", {})[motion] = check_parity(env)
            print(f"{motion}: parity vs CPU MuJoCo:", result["parity"][motion], flush=True)
        if args.breakdown:
            parts = bench_parts(env, max(args.envs), args.steps, args.repeats)
            result.setdefault("breakdowns", {})[motion] = parts
            print(f"{motion}: breakdown", parts, flush=True)
    if args.dump_hlo:
        env, n = models[-1], max(args.envs)
        state = jax.jit(jax.vmap(env.reset))(jax.random.split(jax.random.PRNGKey(0), n))
        hlo = jax.jit(jax.vmap(env.step)).lower(state, jnp.zeros((n, 2))).compile().as_text()
        atomic_write_text(args.out + "_hlo.txt", hlo)
    if args.ceiling:
        result["ceiling"] = {  # 1 GiB; 8192² fp32 at JAX's default precision, chained on GPUs
            "copy_bytes_per_s": measure.copy_ceiling(2**30, args.repeats),
            "matmul_flops_per_s": measure.matmul_ceiling(8192, args.repeats),
        }
        print("ceiling", result["ceiling"], flush=True)
    write(result, pathlib.Path(args.out), append=args.append)
    return result


def write(result: dict, out: pathlib.Path, append: bool = False) -> None:
    """Writes ``out``.json ({"runs": [...]}) and ``out``.md, one section per run; with
    ``append`` the runs already in ``out``.json are kept (CPU and GPU runs in one file)."""
    runs = []
    if append and out.with_suffix(".json").exists():
        runs = json.loads(out.with_suffix(".json").read_text())["runs"]
    runs.append(result)
    atomic_write_json(out.with_suffix(".json"), {"runs": runs})
    lines = [
        "# Env benchmark: steps per second of the navigation env",
        "",
        "`jax.jit` of a `lax.scan` over `jax.vmap(env.step)` (MJX sensors, reward, termination "
        "and auto-reset included), each env driving a fixed random action; best of the timed "
        "calls. Written by `experiments/bench_env.py`; all numbers in the JSON beside this file.",
        "Kernel I/O = bytes read and written by the top-level kernels of the optimised step "
        "(from its HLO); XLA FLOP and bytes accessed = XLA's cost analysis of one step.",
    ]
    for run in runs:
        lines += _section(run)
    # Hand-written readings ("## Reading ..." to the end) survive the regeneration.
    md = out.with_suffix(".md")
    old = md.read_text() if append and md.exists() else ""
    if "\n## Reading" in old:
        lines += ["", *old[old.index("\n## Reading") + 1 :].rstrip("\n").splitlines()]
    writing.write_markdown(md, lines)


def _section(result: dict) -> list[str]:
    lines = [
        "",
        f"## `{result['arena']}` on {result['device']}",
        "",
        f"- host {result['host']} ({result['cpu_count']} CPUs), jax {result['jax']}, "
        f"date {result['date']}; {result['steps_per_scan']} steps per scan",
        f"- command: `{result['command']}`",
        "",
        *writing.markdown_table(
            ("motion", "envs", "M steps/s", "done/step", "state B/env", "kernel I/O B/step",
             "XLA FLOP/step", "XLA B accessed/step"),
            [(r.get("motion", "kinematic"), r["envs"], r["steps_per_s"] / 1e6,
              r["done_per_step"], r["state_bytes_per_env"], r["kernel_io_bytes_per_step"],
              r["xla_flops_per_step"], r["xla_bytes_per_step"]) for r in result["rows"]],
            formats=("", "", ".3f", ".4f", ".0f", ".3g", ".3g", ".3g"),
            align="r",
        ),
    ]  # fmt: skip
    # Runs before the motion models were added hold one breakdown and one parity number.
    breakdowns = result.get("breakdowns") or (
        {"kinematic": result["breakdown"]} if "breakdown" in result else {}
    )
    for motion, parts in breakdowns.items():
        lines += ["", f"Parts of a `{motion}` step at the largest size, same scan shape:", ""]
        for name, part in parts.items():
            lines.append(f"- {name}: {part['steps_per_s'] / 1e6:.3f} M/s")
    parity = result.get("parity") or (
        {"kinematic": result["max_abs_diff_vs_cpu_mujoco"]}
        if "max_abs_diff_vs_cpu_mujoco" in result
        else {}
    )
    for motion, diff in parity.items():
        lines += [
            "",
            f"`{motion}`: MJX readings on this device vs CPU MuJoCo (`mj_forward`, same "
            f"poses): max |diff| = {diff:.2g} m over 100 random poses.",
        ]
    if "ceiling" in result:
        c, best = result["ceiling"], max(result["rows"], key=lambda r: r["steps_per_s"])
        rate = best["steps_per_s"]
        io, floor = rate * best["kernel_io_bytes_per_step"], rate * best["min_bytes_per_step"]
        fl = rate * best["xla_flops_per_step"]
        lines += [
            "",
            f"Ceilings measured in the same run: device copy {c['copy_bytes_per_s'] / 1e9:.0f} "
            f"GB/s (read + write), fp32 matmul {c['matmul_flops_per_s'] / 1e12:.0f} TFLOP/s "
            f"(JAX default precision). At {best['envs']} envs, `{best.get('motion', 'kinematic')}` "
            f"({rate / 1e6:.1f} M steps/s):",
            f"- kernel I/O {best['kernel_io_bytes_per_step']:.3g} B/step → {io / 1e9:.0f} GB/s "
            f"= {io / c['copy_bytes_per_s']:.0%} of the copy rate (L2 can push this past 100%);",
            f"- the minimum traffic (state in + out + action, {best['min_bytes_per_step']:.0f} "
            f"B/step) → {floor / 1e9:.1f} GB/s = {floor / c['copy_bytes_per_s']:.1%} of it;",
            f"- XLA-counted {best['xla_flops_per_step']:.3g} FLOP/step → {fl / 1e12:.2f} TFLOP/s "
            f"= {fl / c['matmul_flops_per_s']:.1%} of the matmul rate.",
        ]
    return lines


if __name__ == "__main__":
    main(tyro.cli(Args))
