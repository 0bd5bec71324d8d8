"""Learner throughput: vmapped ADDPG/ATD3 updates per second against a matmul ceiling.

The learner, not the simulator, is the cost of training (docs/architecture.md, "Training,
populations and scale"): a paper agent is ~10^5 updates of batch 1000. This script times
``Learner.update`` of ``--agents`` vmapped agents (replay sampling + critic step + actor step
every d-th update: the one update step training runs) inside one ``lax.scan`` and, in the
same process,
two ceilings: large matmuls (``measure.matmul_ceiling``: a chain of dependent 8192² products
per call, bf16 or fp32 at JAX's default precision) and a device-to-device copy.
FLOPs per update come from XLA's own cost analysis of the compiled update and from an
analytic count (printed side by side).

    python experiments/bench_learner.py                      # paper sizes, ATD3+AfDP
    python experiments/bench_learner.py --small --agents 1 4 # CPU smoke run

Writes ``results/bench_learner.md`` and ``results/bench_learner.json`` (``--out``).

``--reference TREE`` also runs the benchmark of another checkout (e.g. the commit before a
speed change: ``git worktree add /tmp/ref HEAD~1``, or ``git archive HEAD~1 | tar -x -C
ref`` where a GPU machine gets a copy of the working tree) in a subprocess of the same
command, with the same options (``--program`` too, where that tree knows it:
``reference_program_argv``), and reports both side by side: the previous numbers always come
from the same machine and the same minute as the new ones.
"""

from __future__ import annotations

import argparse
import dataclasses
import itertools
import sys
from pathlib import Path

import jax
import jax.numpy as jnp
import numpy as np

from advisor_jax.agent.config import HParams, parse_agent
from advisor_jax.agent.learner import make_learner
from advisor_jax.agent.networks import PRECISIONS
from advisor_jax.agent.replay_buffer import replay_sample
from advisor_jax.bench import measure, writing
from advisor_jax.bench.learner_loop import (
    SMALL,
    fill_replay,
    make_update_loop,
    require_whole_blocks,
)
from advisor_jax.contract import spec
from advisor_jax.fileio import atomic_write_json
from advisor_jax.training.devices import place
from advisor_jax.training.program import PROGRAMS, network_layout, resolve_program

PRECISION_LABELS = {
    "fp32": "fp32 (JAX's default matmul precision)",
    "bf16": (
        "bf16 hidden layers (fp32 accumulation; on GPUs Adam's m and v in bf16, and held "
        "critics' hidden matrices in bf16 only)"
    ),
}


def dense_macs(sizes: list[tuple[int, int]]) -> int:
    return sum(i * o for i, o in sizes)


# --small: tiny networks for a CPU smoke run (AgentConfig overrides).


def analytic_flops_per_update(cfg) -> float:
    """FLOPs of one update per batch sample: forward = 2·MACs, backward ≈ 2 × forward."""
    h = cfg.actor_hidden
    widths = [spec.OBS_SIZE, *h, spec.ACTION_SIZE]
    actor = dense_macs(list(zip(widths[:-1], widths[1:], strict=True)))
    c = cfg.critic_hidden
    critic = dense_macs(
        [
            (spec.OBS_SIZE, cfg.critic_state_hidden),
            (cfg.critic_state_hidden + spec.ACTION_SIZE, c[0]),
            *zip(c[:-1], c[1:], strict=False),
            (c[-1], 1),
        ]
    )
    k = cfg.n_critics
    # Critic step: target actor fwd, k target critics fwd, k critics fwd + bwd (weights+inputs).
    critic_step = actor + k * critic + 3 * k * critic
    # Actor step: actor fwd, Q1 fwd + input-grad bwd, AfP: Q1 on [2n], actor bwd (weights+inputs).
    actor_step = actor + 2 * critic + (2 * critic if cfg.advisor_policy else 0) + 2 * actor
    return 2.0 * (critic_step + actor_step / cfg.delay)


def xla_flops_per_update(cfg, learner, replay) -> float:
    """XLA's FLOP count of one critic step + 1/d of an actor step (one agent)."""
    hp = HParams()
    state = jax.jit(learner.init)(jax.random.PRNGKey(0))
    batch = replay_sample(replay, jax.random.PRNGKey(1), cfg.batch_size)
    key = jax.random.PRNGKey(2)

    def flops(fn, *args):
        cost = jax.jit(fn).lower(*args).compile().cost_analysis()
        cost = cost[0] if isinstance(cost, list) else cost
        return float(cost.get("flops", float("nan")))

    critic = flops(lambda s, b, k: learner.critic_step(s, b, k, hp)[0], state, batch, key)
    actor = flops(lambda s, b: learner.actor_step(s, b, hp)[0], state, batch)
    return critic + actor / cfg.delay


def time_update_loop(loop, states, replays, keys) -> tuple[float, float]:
    """(seconds of the first call, best of the 3 after it) of ``make_update_loop``'s loop,
    which donates ``states``: every call runs on the previous call's output."""

    def call():
        nonlocal states
        states = loop(states, replays, keys)
        return states

    return measure.first_and_best(call, 3)


def breakdown(cfg, n_agents: int, n_iters: int) -> list[tuple[str, float]]:
    """Seconds per agent-iteration of each piece of an update, vmapped over ``n_agents``."""
    import optax

    from advisor_jax.agent.networks import (
        apply_critics,
        learner_functions,
        make_actor,
        make_critic,
    )

    layout = network_layout()
    learner = make_learner(cfg, layout=layout)
    hp = HParams()
    actor, critic = make_actor(cfg.actor_hidden, cfg.precision), make_critic(cfg, cfg.precision)
    critic_apply = learner_functions(actor, critic, layout)[1].apply
    keys = jax.random.split(jax.random.PRNGKey(0), n_agents)
    states = jax.jit(jax.vmap(learner.init))(keys)
    replays = jax.jit(jax.vmap(fill_replay, in_axes=(None, 0)), static_argnums=0)(
        cfg.buffer_size, keys
    )
    batches = jax.jit(jax.vmap(replay_sample, in_axes=(0, 0, None)), static_argnums=2)(
        replays, keys, cfg.batch_size
    )

    def critic_loss(params, batch):
        q = apply_critics(critic_apply, params, batch.obs, batch.action, layout.inputs_per_critic)
        return jnp.mean(jnp.square(q - batch.reward))

    pieces = {
        "replay sample": lambda s, r, b, k: replay_sample(r, k, cfg.batch_size).obs.sum(),
        "critic fwd+bwd": lambda s, r, b, k: jax.grad(critic_loss)(s.critic, b),
        "critic Adam": lambda s, r, b, k: optax.adam(1e-3).update(s.critic, s.critic_opt, s.critic),
        "critic step": lambda s, r, b, k: learner.critic_step(s, b, k, hp),
        "actor step": lambda s, r, b, k: learner.actor_step(s, b, hp),
    }
    rows = []
    for name, fn in pieces.items():

        def loop(s, r, b, k, fn=fn):
            def body(carry, i):
                out = fn(s, r, b, jax.random.fold_in(k, i))
                # Reduce every output so XLA cannot drop any of the work (adds one read).
                leaves = [x for x in jax.tree_util.tree_leaves(out) if x.dtype == jnp.float32]
                return carry + sum(jnp.sum(x) for x in leaves), None

            return jax.lax.scan(body, jnp.float32(0), jnp.arange(n_iters))[0]

        f = jax.jit(jax.vmap(loop))
        _, best = measure.first_and_best(lambda f=f: f(states, replays, batches, keys), 3)
        rows.append((name, best / (n_agents * n_iters)))
        print(f"  {name:15s} {1e6 * rows[-1][1]:8.1f} µs per agent-iteration")
    return rows


def reference_program_argv(tree: Path, program: str) -> list[str]:
    """``--program`` for the reference tree's benchmark: passed where that tree's
    ``bench_learner.py`` knows it (older trees time the general program only), so that both
    trees time the same loop; a non-general program against a tree without it is refused."""
    script = tree / "experiments" / "bench_learner.py"
    if not script.exists():  # measure.run_reference says so
        return []
    if "--program" in script.read_text():
        return ["--program", program]
    if program != "general":
        raise SystemExit(f"--reference {tree}: its bench_learner.py has no --program, so it "
                         f"would time the general loop, not --program {program}")  # fmt: skip
    return []


def ceiling_words(ceilings: dict[str, float], chain: int, size: int, copy_gbs: float) -> str:
    """The report's sentence on the ceilings measured (``ceilings``: TFLOP/s by precision);
    it names fp32's matmul precision only where an fp32 ceiling was measured."""
    fp32 = "fp32 at JAX's default precision; " if "fp32" in ceilings else ""
    return (
        "Ceilings measured in the same process: "
        + ", ".join(f"{p} matmul {c:.1f} TFLOP/s" for p, c in ceilings.items())
        + f" ({fp32}{chain} dependent {size}² products per call, best of 5), device copy "
        f"{copy_gbs:.0f} GB/s."
    )


def main() -> None:
    parser = argparse.ArgumentParser(
        description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter
    )
    parser.add_argument("--agent", default="ATD3+AfDP")
    parser.add_argument("--agents", type=int, nargs="+", default=[1, 8, 32, 64, 128])
    parser.add_argument("--updates", type=int, default=100, help="updates per timed call")
    parser.add_argument("--small", action="store_true", help="tiny networks (CPU smoke run)")
    parser.add_argument("--out", type=Path, default=Path("results"))
    parser.add_argument("--breakdown", type=int, default=0, metavar="AGENTS",
                        help="also time the pieces of an update at this many agents")  # fmt: skip
    parser.add_argument("--precision", nargs="+", default=["fp32"], choices=["fp32", "bf16"],
                        help="learner precisions to time (AgentConfig.precision)")  # fmt: skip
    parser.add_argument("--reference", type=Path, metavar="TREE",
                        help="also run this checkout's benchmark and compare")  # fmt: skip
    parser.add_argument("--program", default="general", choices=("auto", *PROGRAMS),
                        help="the training program whose update loop to time "
                             "(learner_loop.make_update_loop): general (default), steady, "
                             "latency-bound, or auto: what training picks for each population "
                             "on one device (program.choose_program); passed to --reference "
                             "(which must know it unless general)")  # fmt: skip
    parser.add_argument("--latency-bound", dest="program", action="store_const",
                        const="latency-bound",
                        help="the same as --program latency-bound")  # fmt: skip
    args = parser.parse_args()
    cfg = parse_agent(args.agent, **(SMALL if args.small else {}))
    programs = {}  # (precision, agents) -> the program timed
    for precision, n_agents in itertools.product(args.precision, args.agents):
        program = resolve_program(args.program, place(n_agents, 1), precision)
        try:
            programs[precision, n_agents] = require_whole_blocks(cfg, args.updates, program)
        except ValueError as e:
            parser.error(f"--updates: {e}")
    reference = None
    if args.reference:
        argv = ["--agent", args.agent, "--agents", *map(str, args.agents),
                "--updates", str(args.updates), "--precision", *args.precision,
                *(["--small"] if args.small else [])]  # fmt: skip
        argv += reference_program_argv(args.reference, args.program)
        print(f"reference: {args.reference}")
        reference = measure.run_reference(
            args.reference, "bench_learner.py", argv, "bench_learner.json"
        )

    where = measure.provenance()
    device = f"{where['device']} ({where['backend']}), jax {where['jax']}"
    print(f"device: {device}")
    size, chain = 2048 if args.small else 8192, measure.default_chain()
    ceilings = {p: measure.matmul_ceiling(size, dtype=PRECISIONS[p], chain=chain) / 1e12
                for p in args.precision}  # fmt: skip
    ceiling_tflops = ceilings.get("fp32") or measure.matmul_ceiling(size, chain=chain) / 1e12
    copy_gbs = measure.copy_ceiling((64 if args.small else 2048) * 2**20) / 1e9
    print(f"ceilings: matmul {ceilings} TFLOP/s, copy {copy_gbs:.0f} GB/s")
    analytic = analytic_flops_per_update(cfg) * cfg.batch_size

    rows = []
    for precision, n_agents in itertools.product(args.precision, args.agents):
        cfg = dataclasses.replace(cfg, precision=precision)
        program = programs[precision, n_agents]
        learner, loop = make_update_loop(cfg, args.updates, program, agents_per_device=n_agents)
        keys = jax.random.split(jax.random.PRNGKey(0), n_agents)
        states = jax.jit(jax.vmap(learner.init))(keys)
        replays = jax.jit(jax.vmap(fill_replay, in_axes=(None, 0)), static_argnums=0)(
            cfg.buffer_size, keys
        )
        if not rows or rows[-1]["precision"] != PRECISION_LABELS[precision]:
            one_replay = jax.tree_util.tree_map(lambda x: x[0], replays)
            xla_flops = xla_flops_per_update(cfg, learner, one_replay)
        first, best = time_update_loop(loop, states, replays, keys)
        ups = n_agents * args.updates / best
        tflops = ups * analytic / 1e12
        row = dict(agents=n_agents, agent_updates_per_s=ups, updates_per_s_per_agent=ups / n_agents,
                   tflops=tflops, pct_ceiling=100 * tflops / ceilings[precision],
                   flops_per_update_analytic=analytic, flops_per_update_xla=xla_flops,
                   seconds_per_call=best, first_call_s=first,
                   precision=PRECISION_LABELS[precision], program=program)  # fmt: skip
        rows.append(row)
        print(
            f"{precision} agents {n_agents:4d} ({program}): {ups:10.0f} agent-updates/s  "
            f"{tflops:7.2f} TFLOP/s "
            f"({row['pct_ceiling']:.1f} % of matmul)  GFLOP/update analytic {analytic / 1e9:.2f} "
            f"xla {xla_flops / 1e9:.2f}"
        )

    pieces = breakdown(cfg, args.breakdown, args.updates) if args.breakdown else []
    result = dict(
        **where, breakdown_agents=args.breakdown, breakdown_us={k: 1e6 * v for k, v in pieces},
        agent=cfg.name, config=dataclasses.asdict(cfg), updates_per_call=args.updates,
        matmul_ceiling_tflops=ceiling_tflops, matmul_ceilings_tflops=ceilings, copy_gbs=copy_gbs,
        matmul_ceiling_method=f"{chain} dependent {size}x{size} products per call, best of 5",
        program=args.program, rows=rows,
        reference=None if reference is None else dict(tree=str(args.reference),
                                                      rows=reference["rows"]),
        command=writing.command_line("experiments/bench_learner.py", sys.argv[1:]),
    )  # fmt: skip
    atomic_write_json(args.out / "bench_learner.json", result)
    table = writing.markdown_table(
        ("precision", "agents", "program", "agent-updates/s", "TFLOP/s",
         "% of its matmul ceiling", "GFLOP/update (analytic)", "GFLOP/update (XLA)"),
        [(r["precision"], r["agents"], r["program"], r["agent_updates_per_s"], r["tflops"],
          r["pct_ceiling"], r["flops_per_update_analytic"] / 1e9, r["flops_per_update_xla"] / 1e9)
         for r in rows],
        formats=("", "", "", ",.0f", ".2f", ".1f", ".2f", ".2f"),
        align="r",
    )  # fmt: skip
    lines = [
        "# Learner throughput",
        "",
        f"{cfg.name}, batch {cfg.batch_size}, actor {cfg.actor_hidden}, critic "
        f"{cfg.critic_state_hidden}+{cfg.critic_hidden}, d = {cfg.delay}; {args.updates} "
        "updates per jitted call (replay sampling + critic step + delayed actor step).",
        "",
        f"Device: {device}, {result['date']}. {ceiling_words(ceilings, chain, size, copy_gbs)}",
        "",
        *table,
        "",
        "TFLOP/s uses the analytic count. XLA's count leaves out work done in library calls "
        "(cuBLAS GEMMs) and so changes with the kernels the autotuner picks; it is a lower bound.",
    ]
    if reference is not None:
        before = {
            (r["agents"], r.get("precision", PRECISION_LABELS["fp32"])): r["agent_updates_per_s"]
            for r in reference["rows"]
        }
        lines += [
            "",
            f"Against `{args.reference}` (run in the same command, same options):",
            "",
            *writing.markdown_table(
                ("precision", "agents", "reference agent-updates/s", "this tree", "speed-up"),
                [
                    (
                        r["precision"],
                        r["agents"],
                        before[r["agents"], r["precision"]],
                        r["agent_updates_per_s"],
                        r["agent_updates_per_s"] / before[r["agents"], r["precision"]],
                    )
                    for r in rows
                ],
                formats=("", "", ",.0f", ",.0f", ".2f"),
                align="r",
            ),  # fmt: skip
        ]
    if pieces:
        per_update = 1e6 / rows[-1]["agent_updates_per_s"]
        lines += [
            "",
            f"Pieces of an update at {args.breakdown} agents (µs per agent and call; the "
            f"whole update takes {per_update:.0f} µs at {rows[-1]['agents']} agents):",
            "",
            *writing.markdown_table(
                ("piece", "µs"), ((k, 1e6 * v) for k, v in pieces), ("", ".1f")
            ),
        ]
    lines += ["", f"Command: `{result['command']}`", ""]
    writing.write_markdown(args.out / "bench_learner.md", lines)
    print(np.round([r["agent_updates_per_s"] for r in rows]))


if __name__ == "__main__":
    main()
