"""A small program that asks whether XLA's partitioner keeps a vmapped ``lax.cond`` sharded.

Our sharded training chunk, compiled for GPUs by jax 0.11.2 with Shardy (JAX's default
partitioner), all-gathers parameters and Adam moments inside TD3's delayed actor step, a
``lax.cond`` on an unbatched predicate under ``vmap``; compiled with GSPMD, or for CPUs, it
has no collective (results/multigpu_hlo.md, results/bench_multigpu/README.md). This script
is the same shape in about forty lines, with nothing of ours in it but the HLO reader: a
population of small MLPs sharded over its agent axis, a scan of steps, each an Adam update
of every agent and, every second step (``lax.cond``), a second Adam update and a soft
update of target parameters. It compiles (does not run) the program and lists the
collectives inside the loop (``training.collectives``); exit status 1 if there are any.

    python experiments/shardy_cond_repro.py                       # 2 forced CPU devices
    python experiments/shardy_cond_repro.py --platform gpu        # the GPUs JAX sees
    JAX_USE_SHARDY_PARTITIONER=false python experiments/shardy_cond_repro.py --platform gpu

It does not reproduce the training chunk's all-gathers: on two H200s (jax 0.11.2,
2026-11-27) it has no collective under either partitioner
(results/bench_multigpu/shardy_cond_repro_h200x2.log), so the trigger is in what the chunk
has and this program lacks.
"""

from __future__ import annotations

import argparse
import os
import sys
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--platform", default="cpu", choices=["cpu", "gpu"])
    parser.add_argument("--devices", type=int, default=2)
    parser.add_argument("--agents", type=int, default=8, help="population size")
    parser.add_argument("--width", type=int, default=256, help="hidden layer width")
    parser.add_argument("--steps", type=int, default=10, help="scan length")
    args = parser.parse_args()
    if args.platform == "cpu":
        os.environ["JAX_PLATFORMS"] = "cpu"
        flag = f"--xla_force_host_platform_device_count={args.devices}"
        os.environ["XLA_FLAGS"] = f"{os.environ.get('XLA_FLAGS', '')} {flag}".strip()

    import jax
    import jax.numpy as jnp
    import numpy as np
    import optax
    from jax.sharding import Mesh, NamedSharding, PartitionSpec

    from advisor_jax.training.collectives import find_collectives

    optimizer = optax.adam(1e-3)

    def init(key):
        k1, k2 = jax.random.split(key)
        params = {"w1": jax.random.normal(k1, (16, args.width)) * 0.1,
                  "w2": jax.random.normal(k2, (args.width, 1)) * 0.1}  # fmt: skip
        opt = optimizer.init(params)
        return {"critic": params, "actor": params, "target": params,
                "critic_opt": opt, "actor_opt": opt}  # fmt: skip

    def loss(params, x):
        return jnp.mean(jnp.square(jax.nn.relu(x @ params["w1"]) @ params["w2"]))

    def adam_step(params, opt_state, x):
        updates, opt_state = optimizer.update(jax.grad(loss)(params, x), opt_state, params)
        return optax.apply_updates(params, updates), opt_state

    def delayed(state, x):  # TD3's delayed actor step: an update and soft target updates
        actor, actor_opt = adam_step(state["actor"], state["actor_opt"], x)
        target = jax.tree.map(lambda t, p: 0.995 * t + 0.005 * p, state["target"], actor)
        return {**state, "actor": actor, "actor_opt": actor_opt, "target": target}

    def step(state, x, index):  # index is unbatched: the cond really skips
        critic, critic_opt = adam_step(state["critic"], state["critic_opt"], x)
        state = {**state, "critic": critic, "critic_opt": critic_opt}
        return jax.lax.cond(index % 2 == 0, delayed, lambda s, _: s, state, x)

    def chunk(state, data):
        def body(s, i):
            return step(s, data[i % data.shape[0]], i), None

        return jax.lax.scan(body, state, jnp.arange(args.steps))[0]

    population = jax.vmap(chunk)
    mesh = Mesh(np.array(jax.devices()[: args.devices]), ("agents",))
    agents = NamedSharding(mesh, PartitionSpec("agents"))
    keys = jax.random.split(jax.random.PRNGKey(0), args.agents)
    state = jax.eval_shape(jax.vmap(init), keys)
    data = jax.ShapeDtypeStruct((args.agents, 4, 64, 16), jnp.float32)

    def sharded(tree):
        return jax.tree.map(lambda a: jax.ShapeDtypeStruct(a.shape, a.dtype, sharding=agents), tree)

    compiled = jax.jit(population, in_shardings=(agents, agents), out_shardings=agents)
    hlo = compiled.lower(sharded(state), sharded(data)).compile().as_text()
    found = [c for c in find_collectives(hlo) if c.in_loop]
    partitioner = "Shardy" if getattr(jax.config, "jax_use_shardy_partitioner", True) else "GSPMD"
    print(f"jax {jax.__version__}, {args.devices} {jax.devices()[0].platform} devices, "
          f"{partitioner}: {len(found)} collective(s) inside the loop")  # fmt: skip
    for c in found:
        print(f"  {c.op:20s} {c.shape:28s} {c.bytes:10d} B  {c.source}")
    return 1 if found else 0


if __name__ == "__main__":
    sys.exit(main())
