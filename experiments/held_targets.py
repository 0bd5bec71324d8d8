"""The learner's held networks (``Learner.hold``): same updates, and their memory.

With each hidden layer one GEMM (``agent/gemm_layers.py``, GPUs), a training chunk holds the
target networks' augmented matrices built once per soft update instead of building them in
every critic step (``program.holds_networks``), and, with ``--critics``, the critics
themselves as those matrices (``agent/held_critics.py``, ``program.holds_critics``). This
script checks the two things that change hands, on the default device:

* **parity**: ``--updates`` updates (the delay's actor steps among them) of ``--agents``
  ATD3+AfDP agents at paper sizes, held and not, compiled as training compiles them; prints
  whether every leaf of the final states is equal bit for bit, and the largest difference
  (the held critics agree to rounding, not bit for bit: their module docstring);
* **memory**: the temporaries of the compiled training chunk (``--chunk`` steps, the general
  program) per agent, held and not (``compile().memory_analysis()``).

    python experiments/held_targets.py                   # on the GPU
    python experiments/held_targets.py --critics --precision fp32 bf16
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
from advisor_jax.training.compiler import compiler_options
from advisor_jax.training.program import network_layout
from advisor_jax.training.train import make_train

GPU_LAYOUT = network_layout("gpu")


def _config(precision: str, small: bool):
    """(TrainConfig, HParams) of ATD3+AfDP: ``paper``, or ``quick`` with tiny networks."""
    if small:
        return preset("quick", "ATD3+AfDP", precision=precision, **SMALL)
    return preset("paper", "ATD3+AfDP", precision=precision)


def _layouts(critics: bool):
    """(held, not held): the layouts and whether the chunk holds (``make_train``'s ``hold``);
    ``critics``: both hold the targets, one the critics too."""
    if critics:
        return (GPU_LAYOUT._replace(held_critics=True), True), (GPU_LAYOUT, True)
    return (GPU_LAYOUT, True), (GPU_LAYOUT, False)


def parity(precision: str, n_agents: int, n_updates: int, small: bool, critics: bool) -> dict:
    """Held against not held over ``n_updates`` updates: bit for bit, and the largest
    absolute difference of any leaf."""
    cfg = _config(precision, small)[0].agent
    learners = [(make_learner(cfg, layout=layout), hold) for layout, hold in _layouts(critics)]
    keys = jax.random.split(jax.random.key(0), n_agents)
    replay = jax.jit(jax.vmap(fill_replay, in_axes=(None, 0)), static_argnums=0)(
        cfg.buffer_size, jax.random.split(jax.random.key(1), n_agents)
    )

    def run(state, replay, learner, hold: bool):
        state = learner.hold(state) if hold else state
        for u in range(n_updates):
            k_sample, k_critic = jax.random.split(jax.random.key(10 + u))
            state, _, _ = learner.update(
                state, learner.sample(replay, k_sample), k_critic, HParams(), u
            )
        return learner.release(state)

    init = jax.jit(jax.vmap(learners[0][0].init))(keys)
    options = compiler_options(precision)
    held, built = (
        jax.jit(jax.vmap(lambda s, r, lh=lh: run(s, r, *lh)), compiler_options=options)(
            init, replay
        )
        for lh in learners
    )
    pairs = list(zip(jax.tree.leaves(held), jax.tree.leaves(built), strict=True))
    return dict(
        bit_for_bit=all(np.array_equal(np.asarray(a), np.asarray(b)) for a, b in pairs),
        max_abs_difference=max(float(jnp.max(jnp.abs(a - b))) for a, b in pairs),
    )


def temporaries_per_agent(
    precision: str, n_agents: int, chunk: int, small: bool, critics: bool
) -> dict:
    """MiB of temporaries per agent of the compiled general chunk, held and not."""
    cfg, hp = _config(precision, small)
    cfg = dataclasses.replace(cfg, chunk_steps=chunk)
    out = {}
    for name, (layout, hold) in zip(("held", "built"), _layouts(critics), strict=True):
        trainer = make_train(cfg, False, layout, hold)
        states = jax.eval_shape(
            jax.vmap(trainer.init), jax.random.split(jax.random.key(0), n_agents)
        )
        hps = jax.tree.map(lambda x: jnp.broadcast_to(x, (n_agents, *jnp.shape(x))), hp)
        chunk_fn = jax.jit(jax.vmap(trainer.chunk, in_axes=(0, 0, None)), donate_argnums=0,
                           compiler_options=compiler_options(precision))  # fmt: skip
        memory = chunk_fn.lower(states, hps, jnp.int32(0)).compile().memory_analysis()
        out[name] = memory.temp_size_in_bytes / n_agents / 2**20
    return out


def main(argv=None) -> int:
    parser = writing.check_parser(__doc__)
    parser.add_argument("--chunk", type=int, default=100, help="env steps of the compiled chunk")
    parser.add_argument(
        "--critics", action="store_true", help="the critics held against the targets alone"
    )
    args = parser.parse_args(argv)
    rows = []
    for precision in args.precision:
        checked = parity(precision, args.agents, args.updates, args.small, args.critics)
        row = dict(precision=precision, **checked)
        memory = temporaries_per_agent(precision, args.agents, args.chunk, args.small, args.critics)
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
        f"{args.updates} updates, a {args.chunk}-step chunk; "
        + ("held: the critics and targets, built: the targets alone" if args.critics
           else "held: the targets")
    )  # fmt: skip
    writing.publish_check(
        args.out,
        "experiments/held_targets.py",
        argv,
        "Held networks: parity and memory",
        setup,
        table,
        rows,
    )
    return 0


if __name__ == "__main__":
    sys.exit(main())
