"""1-agent latency-bound chunk: do stable output addresses (donated metrics, device step) remove the launch cost?"""
import dataclasses, json, os, time
from pathlib import Path
import jax, jax.numpy as jnp
from advisor_jax.agent.config import preset
from advisor_jax.training import program
from advisor_jax.training.devices import AXIS, init_population, place, put
from advisor_jax.training.population import agent_keys, build_population

OUT = Path(os.environ["OUT"]) / "w"; OUT.mkdir(parents=True, exist_ok=True)
C = int(os.environ.get("PROBE_CHUNK", "100"))
results = {}
chunk_of = [None]

def build(variant):
    cfg, hp = preset(os.environ.get("PROBE_PRESET", "paper"), "ATD3+AfDP", precision="bf16")
    cfg = dataclasses.replace(cfg, chunk_steps=C, episodes=100_000)
    placement = place(1, 1)
    trainer, init_fn, chunk_fn = program.population_functions(cfg, placement, "latency-bound")
    opts = program.compiler_options("bf16", overlap=True, steady=trainer.steady)
    if variant == "skip_temp":
        opts = dict(opts or {}, xla_gpu_command_buffer_update_mode="SKIP_TEMP")
    chunk = jax.vmap(trainer.chunk, in_axes=(0, 0, None), axis_name=AXIS)
    chunk_of[0] = chunk
    if variant in ("head_rebuilt", "skip_temp"):
        fn = jax.jit(chunk, donate_argnums=0, compiler_options=opts)
    elif variant == "donated_metrics":
        fn = jax.jit(lambda s, h, f, m: chunk(s, h, f), donate_argnums=(0, 3), compiler_options=opts)
    elif variant == "donated_metrics_device_step":
        fn = jax.jit(lambda s, h, f, m: (*chunk(s, h, f), f + C), donate_argnums=(0, 2, 3), compiler_options=opts)
    else:
        fn = chunk_fn
    hp, _ = build_population(hp, {}, seeds=[0]); hp = put(hp, placement)
    state = init_population(init_fn, agent_keys([0]), placement, cfg.episodes)
    return cfg, hp, state, fn

def run(variant):
    cfg, hp, state, fn = build(variant)
    step = 0; metrics = None; fs = jnp.int32(0)
    def call():
        nonlocal state, step, metrics, fs
        if variant.startswith("donated_metrics"):
            if variant == "donated_metrics":
                out = fn(state, hp, jnp.int32(step), metrics)
                state, metrics = out
            else:
                state, metrics, fs = fn(state, hp, fs, metrics)
        else:
            state, metrics = fn(state, hp, jnp.int32(step))
        step += C
        return state
    if variant.startswith("donated_metrics"):  # an initial metrics buffer of the right avals
        avals = jax.eval_shape(chunk_of[0], state, hp, fs)[1]
        metrics = jax.tree.map(lambda a: jnp.zeros(a.shape, a.dtype), avals)
    while step * cfg.envs_per_agent < cfg.agent.warmup + C:
        jax.block_until_ready(call())
    disp, tot = [], []
    for _ in range(8):
        t0 = time.perf_counter(); s = call(); t1 = time.perf_counter(); jax.block_until_ready(s); t2 = time.perf_counter()
        disp.append(t1 - t0); tot.append(t2 - t0)
    t0 = time.perf_counter()
    for _ in range(5): s = call()
    jax.block_until_ready(s); b2b = (time.perf_counter() - t0) / 5
    row = dict(variant=variant, chunk=C, best_s=min(tot), steps_per_s=C / min(tot),
               dispatch_ms_median=1e3 * sorted(disp)[4], b2b_s=b2b, b2b_steps_per_s=C / b2b)
    print(json.dumps(row), flush=True); results[variant] = row
    (OUT / "probe4.json").write_text(json.dumps(results, indent=1))

for v in ["head", "head_rebuilt", "donated_metrics", "donated_metrics_device_step", "skip_temp"]:
    try:
        run(v)
    except Exception as e:
        print("FAILED", v, repr(e)[:600], flush=True)
