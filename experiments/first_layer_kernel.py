"""The critic's first-layer kernel (``agent/masked_wgrad.py``): same updates, and what XLA made.

On GPUs the critic's first hidden layer computes its weight gradient and ReLU mask in one
Pallas kernel (``networks.Layout.first_layer_kernel``, ``program.network_layout``). This
script checks, on the default device, ATD3+AfDP at paper sizes (``--small``: tiny networks):

* **gradients**: one critic step's gradient of the first layer's matrix with and without
  the kernel, on the same batch: the largest difference against the gradient's scale;
* **updates**: ``--updates`` whole updates (the delay's actor steps among them) of
  ``--agents`` agents with and without it, compiled as training compiles them: the largest
  difference of any leaf of the final states;
* **the compiled update**: how many of its custom calls are the kernel, and the library
  GEMMs beside them (so a reader sees the kernel ran where intended and nowhere else);
* **split rows**: the first layer's gradient (random inputs) with the batch rows split as
  1 agent's twin critics split them (``masked_wgrad.row_splits``) against the unsplit
  kernel: how many entries differ, and by how much;
* **mask from the input** (bf16): the kernel that computes the ReLU's mask from the
  layer's input, which ``gemm_layers`` runs for bf16 matrices, against the kernel that
  reads it from the layer's output, batched as 1, 32 and 128 layers: how many entries differ.

Both layouts are the GPU's (``program.network_layout("gpu")``) wherever this runs; off a GPU
the kernel runs in Pallas's interpreter.

    python experiments/first_layer_kernel.py                  # on the GPU
    python experiments/first_layer_kernel.py --small --agents 2 --updates 5   # CPU smoke run

Prints a table; with ``--out`` writes ``first_layer_kernel.md`` and ``.json``.
"""

from __future__ import annotations

import collections
import re
import sys

import jax
import jax.numpy as jnp

from advisor_jax.agent import masked_wgrad
from advisor_jax.agent.config import HParams, preset
from advisor_jax.agent.learner import make_learner
from advisor_jax.agent.replay_buffer import replay_sample
from advisor_jax.bench import writing
from advisor_jax.bench.learner_loop import SMALL, fill_replay
from advisor_jax.training.compiler import compiler_options
from advisor_jax.training.program import network_layout

KERNEL = network_layout("gpu")
WITHOUT = KERNEL._replace(first_layer_kernel=False)


def _learners(precision: str, small: bool = False):
    name, sizes = ("quick", SMALL) if small else ("paper", {})
    cfg = preset(name, "ATD3+AfDP", precision=precision, **sizes)[0].agent
    return cfg, make_learner(cfg, layout=KERNEL), make_learner(cfg, layout=WITHOUT)


def _max_diff(a, b) -> float:
    pairs = zip(jax.tree.leaves(a), jax.tree.leaves(b), strict=True)
    return max(float(jnp.max(jnp.abs(x.astype(jnp.float32) - y.astype(jnp.float32))))
               for x, y in pairs)  # fmt: skip


def gradient_check(precision: str, small: bool = False) -> dict:
    """One critic step from the same state and batch: the new critic parameters' largest
    difference with and without the kernel, against the step's largest change."""
    cfg, with_kernel, without = _learners(precision, small)
    state = with_kernel.init(jax.random.key(0))
    replay = fill_replay(cfg.buffer_size, jax.random.key(1))
    batch = replay_sample(replay, jax.random.key(2), cfg.batch_size)
    options = compiler_options(precision)
    steps = [
        jax.jit(lambda s, b, learner=learner: learner.critic_step(s, b, jax.random.key(3),
                                                                  HParams())[0].critic,
                compiler_options=options)(state, batch)
        for learner in (with_kernel, without)
    ]  # fmt: skip
    return dict(step_difference=_max_diff(*steps), step_size=_max_diff(steps[1], state.critic))


def update_check(
    precision: str, n_agents: int, n_updates: int, small: bool = False
) -> tuple[dict, str]:
    """``n_updates`` vmapped updates with and without the kernel: the largest difference of
    the final states; and the compiled loop's HLO text (with the kernel)."""
    cfg, with_kernel, without = _learners(precision, small)
    keys = jax.random.split(jax.random.key(0), n_agents)
    replay = jax.jit(jax.vmap(fill_replay, in_axes=(None, 0)), static_argnums=0)(
        cfg.buffer_size, jax.random.split(jax.random.key(1), n_agents)
    )
    init = jax.jit(jax.vmap(with_kernel.init))(keys)

    def loop(learner):
        def run(state, replay):
            state = learner.hold(state)
            for u in range(n_updates):
                k_sample, k_critic = jax.random.split(jax.random.key(10 + u))
                state, _, _ = learner.update(
                    state, learner.sample(replay, k_sample), k_critic, HParams(), u
                )
            return learner.release(state)

        return jax.jit(jax.vmap(run), compiler_options=compiler_options(precision))

    compiled = loop(with_kernel).lower(init, replay).compile()
    finals = [compiled(init, replay), loop(without)(init, replay)]
    return dict(update_difference=_max_diff(*finals)), compiled.as_text()


def split_check(precision: str, small: bool = False) -> dict:
    """The first layer's weight gradient of random inputs ([1000, 24] x [1000, 1008] at
    paper sizes) with the rows split as for 1 agent's twin critics, against the unsplit
    kernel."""
    n, k, m = (40, 24, 72) if small else (1000, 24, 1008)
    dtype = {"bf16": jnp.bfloat16, "fp32": jnp.float32}[precision]
    keys = jax.random.split(jax.random.key(4), 3)
    x, y, g = (jax.random.normal(key, shape, dtype)
               for key, shape in zip(keys, [(n, k), (n, m), (n, m)], strict=True))  # fmt: skip
    splits = masked_wgrad.row_splits(2, n, m)
    one, split = (jax.jit(lambda x, y, g, s=s: masked_wgrad.kernel(x, y, g, splits=s))(x, y, g)
                  for s in (1, splits))  # fmt: skip
    differ = one.astype(jnp.float32) != split.astype(jnp.float32)
    return dict(
        splits=splits,
        split_entries_differing=int(differ.sum()),
        entries=one.size,
        split_difference=_max_diff(one, split),
        gradient_scale=float(jnp.max(jnp.abs(one.astype(jnp.float32)))),
    )


def from_input_check(precision: str, small: bool = False) -> dict:
    """bf16: ``masked_wgrad.weight_gradient_from_input`` (the mask ``X @ W > 0`` computed in
    the kernel) against ``masked_wgrad.weight_gradient`` (the mask read from Y), each vmapped
    over 1, 32 and 128 layers (1, 16 and 64 agents' twin critics; small: 1 and 4) as
    training batches them. X normal with its ones column and a zero column, W 0.2 · normal,
    dY 10⁻³ · normal, and Y = relu(X @ W) from XLA's bf16 GEMM, as the forward computes it.
    fp32 layers read Y: None."""
    if precision != "bf16":
        return dict(from_input_entries_differing=None, from_input_entries=None)
    n, k, m = (40, 24, 72) if small else (1000, 24, 1008)
    differing = entries = 0
    for layers in (1, 4) if small else (1, 32, 128):
        keys = jax.random.split(jax.random.key(layers), 3)
        x = jax.random.normal(keys[0], (layers, n, k), jnp.float32)
        x = x.at[..., k - 2].set(1.0).at[..., k - 1].set(0.0).astype(jnp.bfloat16)
        w = (0.2 * jax.random.normal(keys[1], (layers, k, m))).astype(jnp.bfloat16)
        g = (1e-3 * jax.random.normal(keys[2], (layers, n, m))).astype(jnp.bfloat16)
        y = jax.jit(lambda x, w: jax.nn.relu(jnp.einsum("lnk,lkm->lnm", x, w)))(x, w)
        from_y = jax.jit(jax.vmap(masked_wgrad.weight_gradient))(x, y, g)
        from_x = jax.jit(jax.vmap(masked_wgrad.weight_gradient_from_input))(x, w, g)
        differing += int((from_y.astype(jnp.float32) != from_x.astype(jnp.float32)).sum())
        entries += from_y.size
    return dict(from_input_entries_differing=differing, from_input_entries=entries)


def custom_calls(hlo: str) -> dict:
    """Custom-call targets of a compiled HLO text, counted; and how many of them launch the
    kernel (none off a GPU, where Pallas interprets it as ordinary operations)."""
    triton = r'custom_call_target="__gpu\$xla\.gpu\.triton".*'
    kernel = re.compile(triton + masked_wgrad.KERNEL_NAME)
    return dict(
        custom_calls=dict(collections.Counter(re.findall(r'custom_call_target="([^"]+)"', hlo))),
        kernel_calls=sum(bool(kernel.search(line)) for line in hlo.splitlines()),
    )


def main(argv=None) -> int:
    parser = writing.check_parser(__doc__)
    args = parser.parse_args(argv)
    rows = []
    for precision in args.precision:
        updates, hlo = update_check(precision, args.agents, args.updates, args.small)
        rows.append(dict(precision=precision, **gradient_check(precision, args.small), **updates,
                         **custom_calls(hlo), **split_check(precision, args.small),
                         **from_input_check(precision, args.small)))  # fmt: skip
    table = writing.markdown_table(
        ["precision", "one critic step: difference", "the step's largest change",
         f"{args.updates} updates: difference", "kernel launches", "custom calls",
         "rows split: programs per tile", "entries differing", "largest difference",
         "gradient's scale", "mask from the input: entries differing"],
        [[r["precision"], f"{r['step_difference']:.3g}", f"{r['step_size']:.3g}",
          f"{r['update_difference']:.3g}", r["kernel_calls"],
          ", ".join(f"{k} × {v}" for k, v in sorted(r["custom_calls"].items())),
          r["splits"], f"{r['split_entries_differing']} of {r['entries']}",
          f"{r['split_difference']:.3g}", f"{r['gradient_scale']:.3g}",
          "" if r["from_input_entries"] is None
          else f"{r['from_input_entries_differing']} of {r['from_input_entries']}"]
         for r in rows],
    )  # fmt: skip
    setup = (
        f"ATD3+AfDP, {'small' if args.small else 'paper'} sizes, {args.agents} agents, "
        f"{args.updates} updates"
    )
    writing.publish_check(args.out, "experiments/first_layer_kernel.py", argv,
                          "The critic's first-layer kernel: parity and the compiled update",
                          setup, table, rows)  # fmt: skip
    return 0


if __name__ == "__main__":
    sys.exit(main())
