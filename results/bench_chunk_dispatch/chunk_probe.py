"""Where the 1-agent latency-bound chunk's per-chunk cost goes: variants timed, one trace."""
import contextlib, dataclasses, gzip, json, os, sys, time, collections
from pathlib import Path
import jax, jax.numpy as jnp
from advisor_jax.agent.config import preset
from advisor_jax.bench import measure
from advisor_jax.training import program
from advisor_jax.training.devices import init_population, place, put
from advisor_jax.training.population import agent_keys, build_population

OUT = Path(os.environ["OUT"]) / "w"
OUT.mkdir(parents=True, exist_ok=True)
results = {}

def setup(chunk, variant):
    cfg, hp = preset(os.environ.get("PROBE_PRESET", "paper"), "ATD3+AfDP", precision="bf16")
    cfg = dataclasses.replace(cfg, chunk_steps=chunk, episodes=100_000)
    placement = place(1, 1)
    saved = (program.WHOLE_LOOPS, jax.lax.cond)
    if variant == "no_conditional_graphs":
        program.WHOLE_LOOPS = {"xla_gpu_enable_command_buffer": "FUSION,CUBLAS,CUBLASLT,CUSTOM_CALL,CUDNN,DYNAMIC_SLICE_FUSION,WHILE"}
    _, init_fn, chunk_fn = program.population_functions(cfg, placement, "latency-bound")
    hp, _ = build_population(hp, {}, seeds=[0]); hp = put(hp, placement)
    state = init_population(init_fn, agent_keys([0]), placement, cfg.episodes)
    if variant == "steady_only":  # the chunk's cond traced as its steady branch only (timing only)
        jax.lax.cond = lambda p, t, f, *ops: t(*ops)
    try:
        compiled = chunk_fn.lower(state, hp, jnp.int32(0)).compile()
    finally:
        program.WHOLE_LOOPS, jax.lax.cond = saved
    return cfg, hp, state, compiled

def bench(chunk, variant, trace=False):
    cfg, hp, state, compiled = setup(chunk, variant)
    step = 0
    def one():
        nonlocal state, step
        state, _ = compiled(state, hp, jnp.int32(step)); step += chunk
        return state
    while step * cfg.envs_per_agent < cfg.agent.warmup + chunk:
        jax.block_until_ready(one())
    times = [measure.run_timed(one)[1] for _ in range(7)]
    # dispatch alone: time to return from the call, not waiting
    t0 = time.perf_counter(); s = one(); t_disp = time.perf_counter() - t0; jax.block_until_ready(s)
    # back to back, no block between chunks
    t0 = time.perf_counter()
    for _ in range(5): s = one()
    jax.block_until_ready(s); t_b2b = (time.perf_counter() - t0) / 5
    row = dict(variant=variant, chunk=chunk, best_s=min(times), median_s=sorted(times)[3],
               steps_per_s=chunk / min(times), dispatch_s=t_disp, back_to_back_s=t_b2b,
               b2b_steps_per_s=chunk / t_b2b)
    print(json.dumps(row), flush=True)
    results[f"{variant}_{chunk}"] = row
    (OUT / "probe.json").write_text(json.dumps(results, indent=1))
    if trace:
        d = OUT / "trace"
        with jax.profiler.trace(str(d), create_perfetto_trace=True):
            for _ in range(3): jax.block_until_ready(one())
        f = sorted(d.rglob("perfetto_trace.json.gz"))[-1]
        tr = json.loads(gzip.decompress(f.read_bytes()))
        ev = [e for e in tr["traceEvents"] if e.get("ph") == "X" and "dur" in e]
        meta = {(e["pid"], e.get("tid")): e.get("args", {}).get("name", "") for e in tr["traceEvents"] if e.get("ph") == "M" and e.get("name") == "thread_name"}
        pname = {e["pid"]: e.get("args", {}).get("name", "") for e in tr["traceEvents"] if e.get("ph") == "M" and e.get("name") == "process_name"}
        tot = collections.defaultdict(lambda: [0, 0.0])
        for e in ev:
            k = (pname.get(e["pid"], "?")[:30], meta.get((e["pid"], e.get("tid")), "?")[:30], e["name"][:80])
            tot[k][0] += 1; tot[k][1] += e["dur"]
        lines = ["count total_us  process | thread | name (3 chunks)"]
        for k, (n, us) in sorted(tot.items(), key=lambda kv: -kv[1][1])[:80]:
            lines.append(f"{n:6d} {us:10.0f}  {k[0]} | {k[1]} | {k[2]}")
        t0 = min(e["ts"] for e in ev)
        lines.append("\n# timeline, events >= 40 us")
        for e in sorted(ev, key=lambda e: e["ts"]):
            if e["dur"] >= 40:
                lines.append(f"{e['ts']-t0:10.0f} {e['dur']:8.0f}  {pname.get(e['pid'],'?')[:20]} | {meta.get((e['pid'], e.get('tid')),'?')[:25]} | {e['name'][:90]}")
        (OUT / "trace_summary.txt").write_text("\n".join(lines))
        import shutil; shutil.copy(f, OUT / "trace.json.gz")
        print("\n".join(lines[:60]))

C = int(os.environ.get("PROBE_CHUNK", "100"))
for chunk, variant, trace in [(C, "head", True), (C, "no_conditional_graphs", False), (C, "steady_only", False), (10 * C, "steady_only", False)]:
    try:
        bench(chunk, variant, trace)
    except Exception as e:
        print("FAILED", variant, chunk, repr(e)[:500], flush=True)
