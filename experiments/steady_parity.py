"""Does the steady training program compute what the general one does? (issue 17)

On GPUs the training chunk runs its *steady* program once past warm-up: the same steps with
no ``lax.cond`` inside, compiled with overlapping kernels and whole-loop CUDA graphs
(``training.train``, ``training.program``). The two programs fuse and order their
float reductions differently, so they cannot agree bit for bit, and Adam turns tiny
gradient differences into step-size ones. So each chunk after warm-up is run from one state
S three ways: the general program, the steady program, and the general program on S with
every parameter one float32 ulp up. The steady program computes the same steps when it
differs from the general one by no more than that rounding-size change does. Both programs
are built as training builds them for ``--agents`` agents on one device (its per-device
choices: ``program.stores_free``, ``separates_outputs``, held critics).

Where that program compiles without XLA's multi-output fusion (``program.separates_outputs``,
on GPUs), a fourth run builds it with the fusion, as before commit 4e52394, and the report
says whether the two end each chunk bit for bit equal: a fusion choice moves values between
kernels, not the operations that compute them.

    python experiments/steady_parity.py --agents 4 --chunks 3          # GPU, paper sizes
    python experiments/steady_parity.py --preset quick --chunk 100     # CPU, smoke size

Writes ``results/<name>.md`` / ``.json`` (default ``steady_parity``).
"""

from __future__ import annotations

import argparse
import dataclasses
import sys
from pathlib import Path
from unittest import mock

import jax
import jax.numpy as jnp
import numpy as np

from advisor_jax.agent.config import preset
from advisor_jax.bench import measure, writing
from advisor_jax.fileio import atomic_write_json
from advisor_jax.training import compiler, program
from advisor_jax.training.devices import place
from advisor_jax.training.population import agent_keys, build_population
from advisor_jax.training.program import population_functions


def relative_difference(a, b) -> float:
    """||a - b|| / ||a|| over all float leaves of two trees (0: identical; L2 norms)."""
    num = den = 0.0
    for x, y in zip(jax.tree.leaves(a), jax.tree.leaves(b), strict=True):
        x, y = np.asarray(x, np.float64), np.asarray(y, np.float64)
        keep = np.isfinite(x) & np.isfinite(y)  # skipped steps' NaN metrics
        num += float(np.sum((x[keep] - y[keep]) ** 2))
        den += float(np.sum(x[keep] ** 2))
    return (num / den) ** 0.5 if den > 0 else float(num > 0)


def one_ulp_up(state):
    """``state`` with every learner parameter moved up by one float32 ulp: a change of
    rounding size, whose effect after one chunk is the scale a second program's different
    rounding must be compared with."""
    bump = lambda x: np.nextafter(x, np.float32(np.inf)) if x.dtype == np.float32 else x  # noqa: E731
    learner = state.learner.replace(
        actor=jax.tree.map(bump, state.learner.actor),
        critic=jax.tree.map(bump, state.learner.critic),
    )
    return state.replace(learner=learner)


def bits_equal(a, b) -> bool:
    """Whether two trees hold the same bits in every leaf: dtype, shape and bytes."""
    for x, y in zip(jax.tree.leaves(a), jax.tree.leaves(b), strict=True):
        x, y = np.asarray(x), np.asarray(y)
        if x.dtype != y.dtype or x.shape != y.shape or x.tobytes() != y.tobytes():
            return False
    return True


def fused_program(cfg, placement, name: str):
    """The chunk function of ``name`` built with XLA's multi-output fusion, where training
    builds it without (``separates_outputs``, GPUs only); None elsewhere."""
    per_device = placement.n_padded // placement.n_devices
    separate = program.separates_outputs(name, cfg.agent.precision, per_device)
    if jax.default_backend() != "gpu" or not separate:
        return None
    with mock.patch.object(compiler, "SEPARATE_OUTPUTS", {}):  # the options as before 4e52394
        return population_functions(cfg, placement, name)[2]


PARTS = ("actor", "critic", "target_critic")
METRICS = ("loss/critic", "q/mean", "loss/actor")


def compare(args: argparse.Namespace) -> tuple[list[dict], bool]:
    """Per chunk after warm-up, from the general program's state S at its start: general(S)
    against steady(S) and against general(S one ulp up). Returns (rows, steady built)."""
    cfg, hp = preset(args.preset, args.agent, precision=args.precision)
    cfg = dataclasses.replace(cfg, chunk_steps=args.chunk, episodes=100_000)
    placement = place(args.agents, 1)  # training's per-device choices for this population
    _, init_fn, general_fn = population_functions(cfg, placement, "general")
    trainer, _, steady_fn = population_functions(cfg, placement, args.program)
    fused_fn = fused_program(cfg, placement, args.program)
    seeds = list(range(args.agents))
    hp, _ = build_population(hp, {}, seeds=seeds)
    state, step, rows = init_fn(agent_keys(seeds)), 0, []
    warmup_chunks = -(-cfg.agent.warmup // (cfg.envs_per_agent * args.chunk))
    for c in range(warmup_chunks + args.chunks):
        start = jax.device_get(state)  # the chunk functions donate their input
        state, metrics = general_fn(state, hp, jnp.int32(step))
        if c >= warmup_chunks:
            general = jax.device_get((state, metrics))
            other = {
                "steady": jax.device_get(steady_fn(start, hp, jnp.int32(step))),
                "one ulp": jax.device_get(general_fn(one_ulp_up(start), hp, jnp.int32(step))),
            }
            row = dict(first_step=step)
            if fused_fn is not None:
                fused = jax.device_get(fused_fn(start, hp, jnp.int32(step)))
                row["steady/bits_equal_fused"] = bits_equal(other["steady"], fused)
            for name, (o_state, o_metrics) in other.items():
                g, o = general[0], o_state
                row[f"{name}/counters_equal"] = bool(
                    np.array_equal(g.learner.critic_updates, o.learner.critic_updates)
                    and np.array_equal(g.learner.actor_updates, o.learner.actor_updates)
                )
                for part in PARTS:
                    row[f"{name}/{part}"] = relative_difference(
                        getattr(g.learner, part), getattr(o.learner, part)
                    )
                for key in METRICS:
                    row[f"{name}/{key}"] = relative_difference(general[1][key], o_metrics[key])
            rows.append(row)
        step += args.chunk
    return rows, trainer.steady


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--preset", default="paper")
    parser.add_argument("--agent", default="ATD3+AfDP")
    parser.add_argument("--agents", type=int, default=4)
    parser.add_argument("--precision", default="bf16", choices=["fp32", "bf16"])
    parser.add_argument("--chunk", type=int, default=100, help="env steps per chunk")
    parser.add_argument("--chunks", type=int, default=3, help="chunks after warm-up")
    parser.add_argument("--program", default="latency-bound", choices=["steady", "latency-bound"],
                        help="the conditional-free program set against the general one "
                        "(program.PROGRAMS)")  # fmt: skip
    parser.add_argument("--name", default="steady_parity")
    parser.add_argument("--out", type=Path, default=Path("results"))
    args = parser.parse_args()

    rows, built = compare(args)
    if not built:
        sys.exit(f"no steady program for this config (--chunk {args.chunk}: a multiple of d?)")
    where = measure.provenance()
    result = dict(**where, **{k: v for k, v in vars(args).items() if k != "out"}, rows=rows)
    atomic_write_json(args.out / f"{args.name}.json", result)

    header = ["first step", "against", "counters equal", *PARTS, *METRICS]
    table = writing.markdown_table(
        header,
        [[r["first_step"], name, str(r[f"{name}/counters_equal"]),
          *[r[f"{name}/{k}"] for k in (*PARTS, *METRICS)]]
         for r in rows for name in ("steady", "one ulp")],
        formats=("", "", "", ".1e"),
    )  # fmt: skip
    command = writing.command_line(
        "experiments/steady_parity.py", writing.changed_options(parser, args)
    )
    lines = [
        "# Steady against general training program (issue 17)",
        "",
        f"{args.agent}, preset `{args.preset}`, {args.precision}, {args.agents} agents, "
        f"{args.chunk}-step chunks; {where['device']} ({where['backend']}), jax {where['jax']}, "
        f"{where['date']}. Each chunk after warm-up starts from the general program's state S "
        "and is run three ways: general(S), steady(S), and general(S with every actor and "
        "critic parameter one float32 ulp up). Columns: ||general(S) - other|| / "
        "||general(S)|| of the parameters at the chunk's end and of the chunk's per-step "
        "metrics (skipped actor steps left out), and whether the update counters agree. The "
        "one-ulp row is the size of a rounding change after one chunk (Adam turns tiny "
        "gradient differences into step-size ones); the steady program computes the same "
        "steps when its row is of that size.",
        "",
        *table,
        "",
        f"Command: `{command}`",
    ]
    fused = [r["steady/bits_equal_fused"] for r in rows if "steady/bits_equal_fused" in r]
    if fused:
        lines[-2:-2] = [
            "",
            f"Built with XLA's multi-output fusion (as before commit 4e52394), the {args.program} "
            f"program ended {sum(fused)} of {len(fused)} chunks bit for bit equal to the "
            "program as training builds it (without, `program.separates_outputs`).",
        ]
    writing.write_markdown(args.out / f"{args.name}.md", lines, echo=True)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
