"""1-agent latency-bound chunk: is the per-chunk host cost a graph update forced by new buffers?"""
import dataclasses, json, os, time
from pathlib import Path
import numpy as np
import jax, jax.numpy as jnp
from advisor_jax.agent.config import preset
from advisor_jax.training import program
from advisor_jax.training.devices import init_population, place, put
from advisor_jax.training.population import agent_keys, build_population

OUT = Path(os.environ["OUT"]) / "w"; OUT.mkdir(parents=True, exist_ok=True)
C = int(os.environ.get("PROBE_CHUNK", "100"))
results = {}

def build(state_only):
    cfg, hp = preset(os.environ.get("PROBE_PRESET", "paper"), "ATD3+AfDP", precision="bf16")
    cfg = dataclasses.replace(cfg, chunk_steps=C, episodes=100_000)
    placement = place(1, 1)
    trainer, init_fn, chunk_fn = program.population_functions(cfg, placement, "latency-bound")
    if state_only:
        chunk = jax.vmap(trainer.chunk, in_axes=(0, 0, None))
        chunk_fn = jax.jit(lambda s, h, f: chunk(s, h, f)[0], donate_argnums=0,
                           compiler_options=program.compiler_options("bf16", overlap=True, steady=True))
    hp, _ = build_population(hp, {}, seeds=[0]); hp = put(hp, placement)
    state = init_population(init_fn, agent_keys([0]), placement, cfg.episodes)
    return cfg, hp, state, chunk_fn

def run(label, state_only, variants):
    cfg, hp, state, fn = build(state_only)
    step = 0; kept = []
    def call(fs=None, keep=False):
        nonlocal state, step
        fs = jnp.int32(step) if fs is None else fs
        out = fn(state, hp, fs)
        if state_only: state = out
        else:
            state, m = out
            if keep: kept.append(m)
        step += C
        return state
    while step * cfg.envs_per_agent < cfg.agent.warmup + C:
        jax.block_until_ready(call())
    fixed = jnp.int32(step)
    for v in variants:
        disp, tot = [], []
        for _ in range(8):
            t0 = time.perf_counter()
            s = call(fixed if "fixed_step" in v else None, keep="keep" in v)
            t1 = time.perf_counter(); jax.block_until_ready(s); t2 = time.perf_counter()
            disp.append(t1 - t0); tot.append(t2 - t0)
        t0 = time.perf_counter()
        for _ in range(5): s = call(fixed if "fixed_step" in v else None, keep="keep" in v)
        jax.block_until_ready(s); b2b = (time.perf_counter() - t0) / 5
        row = dict(label=label, variant=v, chunk=C, best_s=min(tot), steps_per_s=C / min(tot),
                   dispatch_ms_median=1e3 * sorted(disp)[4], b2b_s=b2b, b2b_steps_per_s=C / b2b)
        print(json.dumps(row), flush=True); results[f"{label}/{v}"] = row
        kept.clear()
    (OUT / "probe3.json").write_text(json.dumps(results, indent=1))

# host cost of making the step argument
for name, mk in [("jnp.int32", lambda i: jnp.int32(i)), ("device_put(np.int32)", lambda i: jax.device_put(np.int32(i)))]:
    xs = [mk(i) for i in range(50)]; jax.block_until_ready(xs)
    t0 = time.perf_counter(); xs = [mk(i) for i in range(200)]; t = (time.perf_counter() - t0) / 200
    print(f"host cost of {name}: {t*1e6:.0f} us", flush=True)

run("with_metrics", False, ["drop", "keep", "fixed_step", "fixed_step+keep", "drop"])
run("state_only", True, ["drop", "fixed_step"])
