"""The learner's held target networks (``Learner.hold``): same updates, and their memory.

With each hidden layer one GEMM (``agent/gemm_layers.py``, GPUs), a training chunk holds the
target networks' augmented matrices built once per soft update instead of building them in
every critic step (``program.holds_networks``). This script checks the two things that
change hands, on the default device:

* **parity**: ``--updates`` updates (the delay's actor steps among them) of ``--agents``
  ATD3+AfDP agents at paper sizes, with the targets held and without, compiled as training
  compiles them; prints whether every leaf of the final states is equal bit for bit, and
  the largest difference;
* **memory**: the temporaries of the compiled training chunk (``--chunk`` steps, the general
  program) per agent, with and without the hold (``compile().memory_analysis()``).

    python experiments/held_targets.py                   # on the GPU
    python experiments/held_targets.py --small --agents 2 --chunk 8   # CPU smoke run

Both use the GPU's network layout wherever they run (``program.network_layout("gpu")``), so
that a CPU run checks the same program. Prints a table; with ``--out`` writes
``held_targets.md`` and ``.json``.
"""

from __future__ import annotations

import dataclasses
import sys

import jax
import jax.numpy as jnp
import numpy as np

from advisor_jax.agent.config import HParams, preset
from advisor_jax.agent.learner import make_learner
from advisor_jax.bench import writing
from advisor_jax.bench.learner_loop import SMALL, fill_replay
from advisor_jax.training.program import compiler_options, network_layout
from advisor_jax.training.train import make_train

GPU_LAYOUT = network_layout("gpu")


def _config(precision: str, small: bool):
    """(TrainConfig, HParams) of ATD3+AfDP: ``paper``, or ``quick`` with tiny networks."""
    if small:
        return preset("quick", "ATD3+AfDP", precision=precision, **SMALL)
    return preset("paper", "ATD3+AfDP", precision=precision)


def parity(precision: str, n_agents: int, n_updates: int, small: bool) -> dict:
    """Held against built targets over ``n_updates`` updates: bit for bit, and the largest
    absolute difference of any leaf."""
    cfg = _config(precision, small)[0].agent
    learner = make_learner(cfg, layout=GPU_LAYOUT)
    keys = jax.random.split(jax.random.key(0), n_agents)
    replay = jax.jit(jax.vmap(fill_replay, in_axes=(None, 0)), static_argnums=0)(
        cfg.buffer_size, jax.random.split(jax.random.key(1), n_agents)
    )

    def run(state, replay, hold: bool):
        state = learner.hold(state) if hold else state
        for u in range(n_updates):
            k_sample, k_critic = jax.random.split(jax.random.key(10 + u))
            state, _, _ = learner.update(state, replay, k_sample, k_critic, HParams(), u)
        return learner.release(state)

    init = jax.jit(jax.vmap(learner.init))(keys)
    options = compiler_options(precision)
    held, built = (
        jax.jit(jax.vmap(lambda s, r, h=h: run(s, r, h)), compiler_options=options)(init, replay)
        for h in (True, False)
    )
    pairs = list(zip(jax.tree.leaves(held), jax.tree.leaves(built), strict=True))
    return dict(
        bit_for_bit=all(np.array_equal(np.asarray(a), np.asarray(b)) for a, b in pairs),
        max_abs_difference=max(float(jnp.max(jnp.abs(a - b))) for a, b in pairs),
    )


def temporaries_per_agent(precision: str, n_agents: int, chunk: int, small: bool) -> dict:
    """MiB of temporaries per agent of the compiled general chunk, without and with the hold."""
    cfg, hp = _config(precision, small)
    cfg = dataclasses.replace(cfg, chunk_steps=chunk)
    out = {}
    for hold in (False, True):
        trainer = make_train(cfg, False, GPU_LAYOUT, hold)
        states = jax.eval_shape(
            jax.vmap(trainer.init), jax.random.split(jax.random.key(0), n_agents)
        )
        hps = jax.tree.map(lambda x: jnp.broadcast_to(x, (n_agents, *jnp.shape(x))), hp)
        chunk_fn = jax.jit(jax.vmap(trainer.chunk, in_axes=(0, 0, None)), donate_argnums=0,
                           compiler_options=compiler_options(precision))  # fmt: skip
        memory = chunk_fn.lower(states, hps, jnp.int32(0)).compile().memory_analysis()
        out["held" if hold else "built"] = memory.temp_size_in_bytes / n_agents / 2**20
    return out


def main(argv=None) -> int:
    parser = writing.check_parser(__doc__)
    parser.add_argument("--chunk", type=int, default=100, help="env steps of the compiled chunk")
    args = parser.parse_args(argv)
    rows = []
    for precision in args.precision:
        row = dict(precision=precision, **parity(precision, args.agents, args.updates, args.small))
        memory = temporaries_per_agent(precision, args.agents, args.chunk, args.small)
        rows.append(dict(row, temp_mib_per_agent=memory))
    table = writing.markdown_table(
        ["precision", "bit for bit", "largest difference", "temporaries MiB/agent, built",
         "held", "held − built"],
        [[r["precision"], r["bit_for_bit"], f"{r['max_abs_difference']:.3g}",
          f"{r['temp_mib_per_agent']['built']:.2f}", f"{r['temp_mib_per_agent']['held']:.2f}",
          f"{r['temp_mib_per_agent']['held'] - r['temp_mib_per_agent']['built']:+.2f}"]
         for r in rows],
    )  # fmt: skip
    setup = (
        f"ATD3+AfDP, {'small' if args.small else 'paper'} sizes, {args.agents} agents, "
        f"{args.updates} updates, a {args.chunk}-step chunk"
    )
    writing.publish_check(
        args.out,
        "experiments/held_targets.py",
        argv,
        "Held target networks: parity and memory",
        setup,
        table,
        rows,
    )
    return 0


if __name__ == "__main__":
    sys.exit(main())
