"""Our full training step against a generic vmapped JAX TD3 (rejax), in one command.

rejax's TD3 (``rejax.TD3``, gymnax Pendulum-v1) is given our preset's network sizes (actor
600-300, critic 1000-500-600 at ``paper``; ReLU), batch, replay size and policy delay, one
environment per seed and one update per environment step, and is vmapped over ``--agents``
seeds like our population. Its speed is the slope of two whole training calls of E and 2E
steps per seed (E = ``--steps``; by default 20,000 / seeds, at least 2,000): the difference
leaves out its compile, its uniform buffer fill and its fixed costs. Ours is
``advisor_jax.bench.full_step`` (best chunk past the warm-up): our step also runs the arena
with its 16 range sensors, the advisor and Eq. 1's selector, which Pendulum does not have.
rejax computes in fp32; ``--precision`` picks ours (issue 36 compares at the same
precision: fp32). The files are written after each population, so a run cut short keeps
the rows it measured.

    pip install -e ".[peers]"      # rejax 0.1.3 with gymnax 0.0.9 (gymnax 1.0's step differs)
    python experiments/bench_peers.py --agents 1 64                       # GPU, paper sizes
    python experiments/bench_peers.py --preset quick --agents 2 --steps 400 --chunk 100  # CPU

Writes ``results/<name>.md`` / ``.json`` (``--name``, default bench_peers): a row per
population with both rates and ours / rejax, and the versions of rejax, gymnax and distrax.
"""

from __future__ import annotations

import argparse
import sys
import time
from importlib import metadata
from pathlib import Path

import jax
import numpy as np

from advisor_jax.agent.config import preset
from advisor_jax.bench import measure, writing
from advisor_jax.bench.full_step import full_step
from advisor_jax.fileio import atomic_write_json

PEER_PACKAGES = ("rejax", "gymnax", "distrax")


def _tfp_on_current_jax() -> None:
    """rejax imports distrax, whose tensorflow-probability (0.25, the last release) registers
    a type in three jax tables that jax 0.5 removed, and so fails to import on the jax we
    run. Empty tables let it import; nothing rejax's TD3 runs reads them."""
    import jax.core
    import jax.interpreters.xla

    for module, name in (
        (jax.interpreters.xla, "pytype_aval_mappings"),
        (jax.interpreters.xla, "canonicalize_dtype_handlers"),
        (jax.core, "pytype_aval_mappings"),
    ):
        if not hasattr(module, name):
            setattr(module, name, {np.ndarray: None})


def rejax_td3(preset_name: str, agent: str, steps: int):
    """rejax's TD3 on Pendulum with our preset's sizes, training ``steps`` env steps per seed
    (one evaluation at the end; none at the start)."""
    _tfp_on_current_jax()
    from flax import linen as nn
    from rejax import TD3
    from rejax.networks import DeterministicPolicy, QNetwork

    cfg, _ = preset(preset_name, agent)
    a = cfg.agent
    td3 = TD3.create(
        env="Pendulum-v1",
        num_envs=1,
        batch_size=a.batch_size,
        buffer_size=a.buffer_size,
        fill_buffer=a.batch_size,
        policy_delay=a.policy_delay,
        num_epochs=1,
        total_timesteps=steps,
        eval_freq=steps,
        skip_initial_evaluation=True,
    )
    space = td3.env.action_space(td3.env_params)
    actor = DeterministicPolicy(
        int(np.prod(space.shape)),
        (space.low, space.high),
        hidden_layer_sizes=tuple(a.actor_hidden),
        activation=nn.relu,
    )
    critic = QNetwork(
        hidden_layer_sizes=(a.critic_state_hidden, *a.critic_hidden), activation=nn.relu
    )
    return td3.replace(actor=actor, critic=critic)


def _best_call(algo, keys, repeats: int) -> float:
    """Seconds of the fastest of ``repeats`` calls of one compiled, vmapped training."""
    train = jax.jit(jax.vmap(algo.train)).lower(keys).compile()
    times = []
    for _ in range(repeats):
        start = time.perf_counter()
        jax.block_until_ready(train(keys))
        times.append(time.perf_counter() - start)
    return min(times)


def rejax_rate(preset_name: str, agent: str, n: int, steps: int, repeats: int) -> dict:
    """Agent env-steps/s of rejax's TD3 vmapped over ``n`` seeds: ``steps`` more steps per
    seed over the extra time they take (best of ``repeats`` per length, one compile each)."""
    keys = jax.random.split(jax.random.PRNGKey(0), n)
    short = _best_call(rejax_td3(preset_name, agent, steps), keys, repeats)
    long = _best_call(rejax_td3(preset_name, agent, 2 * steps), keys, repeats)
    if long <= short:
        raise SystemExit(
            f"rejax: {2 * steps} steps took no longer than {steps} ({long:.3f} s against "
            f"{short:.3f} s): raise --steps"
        )
    return dict(agent_steps_per_s=n * steps / (long - short), short_s=short, long_s=long)


def main(argv=None) -> dict:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--preset", default="paper")
    parser.add_argument("--agent", default="ATD3+AfDP", help="our agent type (a TD3 learner)")
    parser.add_argument("--agents", type=int, nargs="+", default=[1, 64])
    parser.add_argument(
        "--steps",
        type=int,
        default=0,
        help="rejax: E of the E and 2E step runs per seed (default 20,000 / agents, at least "
        "2,000: a 64-seed population's calls take about 20 and 40 s on an H100)",
    )
    parser.add_argument("--chunk", type=int, default=500, help="ours: env steps per call")
    parser.add_argument("--repeats", type=int, default=3)
    parser.add_argument("--precision", default="fp32", choices=["fp32", "bf16"])
    parser.add_argument("--name", default="bench_peers", help="report file name")
    parser.add_argument("--out", type=Path, default=Path("results"))
    args = parser.parse_args(argv)
    try:
        versions = {name: metadata.version(name) for name in PEER_PACKAGES}
    except metadata.PackageNotFoundError as missing:
        raise SystemExit(f'{missing.name} is not installed: pip install -e ".[peers]"') from None
    where = measure.provenance()
    print(f"device: {where['device']} ({where['backend']}), jax {where['jax']}, {versions}")
    command = writing.command_line(
        "experiments/bench_peers.py", sys.argv[1:] if argv is None else argv
    )
    rows = []
    for n in args.agents:
        steps = args.steps or max(2_000, 20_000 // n)
        ours = full_step(args.preset, args.agent, n, 1, args.precision, args.chunk, args.repeats)
        peer = rejax_rate(args.preset, args.agent, n, steps, args.repeats)
        rows.append(
            dict(
                agents=n,
                ours=ours["agent_steps_per_s"],
                rejax=peer["agent_steps_per_s"],
                ratio=ours["agent_steps_per_s"] / peer["agent_steps_per_s"],
                ours_precision=args.precision,
                rejax_steps=steps,
                rejax_seconds=(peer["short_s"], peer["long_s"]),
            )
        )
        print(
            f"agents {n:4d}: ours {rows[-1]['ours']:10,.0f}, rejax {rows[-1]['rejax']:10,.0f} "
            f"agent env-steps/s, ours / rejax {rows[-1]['ratio']:.2f}"
        )
        result = write(args, where, versions, rows, command)  # after each row: nothing lost
    return result


def write(args, where: dict, versions: dict, rows: list[dict], command: str) -> dict:
    """``--out/--name``.json and .md of the rows measured so far."""
    result = dict(
        **where,
        preset=args.preset,
        agent=args.agent,
        chunk=args.chunk,
        peers=versions,
        rows=rows,
        command=command,
    )
    args.out.mkdir(parents=True, exist_ok=True)
    atomic_write_json(args.out / f"{args.name}.json", result)
    lines = [
        "# Our full training step against rejax's TD3",
        "",
        f"{where['device']} ({where['backend']}), jax {where['jax']}, "
        + ", ".join(f"{k} {v}" for k, v in versions.items())
        + f", {where['date']}. Ours: {args.agent} at `{args.preset}`, {args.precision}; "
        "rejax: TD3 on gymnax Pendulum-v1, the same network sizes, batch, replay size and "
        "policy delay, fp32. Agent env-steps/s (module docstring of "
        "experiments/bench_peers.py for how each is timed).",
        "",
        *writing.markdown_table(
            ("agents", "ours", "rejax TD3", "ours / rejax", "rejax E (steps per seed)"),
            [(r["agents"], r["ours"], r["rejax"], r["ratio"], r["rejax_steps"]) for r in rows],
            formats=("", ",.0f", ",.0f", ".2f", ","),
            align="r",
        ),
        "",
        f"Command: `{result['command']}`",
    ]
    writing.write_markdown(args.out / f"{args.name}.md", lines, echo=len(rows) == len(args.agents))
    return result


if __name__ == "__main__":
    main()
