"""A held critic matrix's weight gradient with Adam's pass in the GEMM's epilogue: does it pay?

In a bf16 learner's critic step (``agent/held_critics.py``) each large held matrix gets its
weight gradient from a cuBLAS GEMM, ``dW = xᵀ d`` (x the layer's input, d the gradient at
its output, both ``[batch, ·]``), written in bf16, and then Adam's pass (``agent/adam.py``),
which reads that gradient, m, v and the matrix and writes m, v and the matrix: 14 bytes per
entry at the memory's bandwidth, 14 % of the 64-agent step (``results/bench_step_costs/``).
A GEMM that ran Adam in its epilogue would skip the gradient's write and read and hide the
pass under the GEMM's arithmetic, if its GEMM kept cuBLAS's pace. cuBLAS takes no such
epilogue, so the candidate is a Pallas kernel (its Triton backend). Timed here, in one
process, for ``--layers`` matrices (64 agents' twin critics: 128) at the paper's shapes:

* ``cublas_gemm``: the GEMM alone, as XLA runs it (cuBLAS), bf16 out;
* ``xla_reference``: that GEMM and training's Adam step (``epilogue``: bf16 m, v and matrix,
  v and the matrix rounded stochastically) with the gradient norm's row sums, as XLA fuses
  them; ``exact=False`` rounds to nearest (no hashes);
* ``pallas_gemm``: the same GEMM as a Pallas kernel, bf16 out, per tile configuration
  (rows, columns, batch rows per step, warps, pipeline stages);
* ``pallas_fused``: that kernel with ``epilogue`` and the row sums after its reduction.

    python experiments/bench_wgrad_adam.py --layers 128               # on the GPU
    python experiments/bench_wgrad_adam.py --out /tmp                 # CPU: the check only

The structure mask and the tied rows (``held_critics.gradient``) are left out. Every run
first checks the fused kernel against the reference on a small case (Pallas's interpreter
off a GPU), and on a GPU at full size too. Writes ``--out``/``bench_wgrad_adam.json`` and
``.md``.
"""

from __future__ import annotations

import functools
import time
import traceback

import jax
import jax.numpy as jnp
from jax.experimental import pallas as pl
from jax.experimental.pallas import triton as pl_triton

from advisor_jax.agent import adam
from advisor_jax.bench import measure, writing

B1, B2, EPS = 0.9, 0.999, 1e-8
SHAPES = ((1008, 504), (504, 608))
"""The critics' two large held matrices at the paper's sizes (rows × columns)."""
BATCH = 1000
CONFIGS = ((128, 128, 64, 8, 3), (128, 128, 32, 4, 4), (128, 128, 64, 4, 3),
           (64, 128, 64, 4, 4), (128, 256, 64, 8, 3), (128, 64, 64, 4, 4))  # fmt: skip
"""Pallas tiles: (matrix rows, matrix columns, batch rows per step, warps, stages)."""


def epilogue(g, p, mu, nu, count, lr, exact=True):
    """Training's Adam step on one matrix from its fp32 gradient ``g``: the arithmetic of
    ``adam.adam(lr, bf16, nu_bf16=True).update`` and ``adam.apply_updates`` (bf16 m; v and
    the matrix rounded stochastically, salted with ``count``, the step's count after its
    increment). ``exact=False``: everything rounded to nearest. → (matrix, m, v), bf16."""
    m = (1 - B1) * g + B1 * mu.astype(jnp.float32)
    v = (1 - B2) * g**2 + B2 * nu.astype(jnp.float32)
    m_hat = m / (1 - B1**count).astype(jnp.float32)
    v_hat = v / (1 - B2**count).astype(jnp.float32)
    new = p.astype(jnp.float32) + -lr * (m_hat / (jnp.sqrt(v_hat) + EPS))
    if not exact:
        return new.astype(jnp.bfloat16), m.astype(jnp.bfloat16), v.astype(jnp.bfloat16)
    v_out = adam.stochastic_bf16(v, adam.dither(p, count))
    return adam.rounded_like(new, p, count), m.astype(jnp.bfloat16), v_out


def reference(x, d, p, mu, nu, count, lr, exact=True):
    """XLA: the bf16 GEMM, then ``epilogue`` and the row sums of g²."""
    g = jnp.einsum("lnk,lnm->lkm", x, d).astype(jnp.float32)
    return (*epilogue(g, p, mu, nu, count, lr, exact), jnp.sum(g * g, axis=-1))


def _kernel(x_ref, d_ref, *refs, tile, fused, exact):
    bm, bn, bk = tile
    layer = pl.program_id(0)
    n, k = x_ref.shape[1:]
    row0 = jnp.minimum(pl.program_id(1) * bm, k - bm)  # the last tiles overlap the one before
    col0 = jnp.minimum(pl.program_id(2) * bn, d_ref.shape[2] - bn)

    def step(i, acc):
        b0 = jnp.minimum(i * bk, n - bk)
        fresh = (b0 + jnp.arange(bk)) >= i * bk  # batch rows no earlier step summed
        xt = x_ref[layer, pl.ds(b0, bk), pl.ds(row0, bm)]
        xt = jnp.where(fresh[:, None], xt, jnp.zeros((), xt.dtype))
        return acc + pl_triton.dot(xt, d_ref[layer, pl.ds(b0, bk), pl.ds(col0, bn)], trans_a=True)

    acc = jax.lax.fori_loop(0, pl.cdiv(n, bk), step, jnp.zeros((bm, bn), jnp.float32))
    at = (layer, pl.ds(row0, bm), pl.ds(col0, bn))
    if not fused:
        refs[0][at] = acc.astype(refs[0].dtype)
        return
    p_ref, mu_ref, nu_ref, s_ref, p_out, mu_out, nu_out, rows_out = refs
    g = acc.astype(jnp.bfloat16).astype(jnp.float32)  # the bf16 gradient the reference reads
    count = s_ref[0].astype(jnp.int32)
    p_out[at], mu_out[at], nu_out[at] = epilogue(g, p_ref[at], mu_ref[at], nu_ref[at], count,
                                                 s_ref[1], exact)  # fmt: skip
    fresh_cols = (col0 + jnp.arange(bn)) >= pl.program_id(2) * bn
    squares = jnp.where(fresh_cols[None, :], g * g, 0.0)
    rows_out[layer, pl.ds(row0, bm), pl.program_id(2)] = jnp.sum(squares, axis=1)


def pallas(x, d, *adam_args, config, fused, exact=True, interpret=False):
    """The Pallas GEMM ``xᵀ d`` per layer (``fused``: with ``epilogue`` and the row sums of g²,
    ``adam_args`` = (matrix, m, v, count, lr)); ``config``: a ``CONFIGS`` entry."""
    (n_layers, _, k), m = x.shape, d.shape[2]
    bm, bn, bk, warps, stages = config
    grid = (n_layers, pl.cdiv(k, bm), pl.cdiv(m, bn))
    call = functools.partial(
        pl.pallas_call,
        functools.partial(_kernel, tile=(bm, bn, bk), fused=fused, exact=exact),
        grid=grid,
        compiler_params=pl_triton.CompilerParams(num_warps=warps, num_stages=stages),
        interpret=interpret,
    )
    matrix = jax.ShapeDtypeStruct((n_layers, k, m), jnp.bfloat16)
    if not fused:
        return call(out_shape=matrix, name="wgrad")(x, d)
    p, mu, nu, count, lr = adam_args
    scalars = jnp.stack([jnp.asarray(count, jnp.float32), jnp.asarray(lr, jnp.float32)])
    rows = jax.ShapeDtypeStruct((n_layers, k, grid[2]), jnp.float32)
    out = call(out_shape=(matrix,) * 3 + (rows,), name="wgrad_adam")(x, d, p, mu, nu, scalars)
    return (*out[:3], out[3].sum(-1))


def operands(n_layers, n, k, m, seed=0):
    """x (a ReLU's output), d, and the matrix, m and v of a few steps' scale, bf16; count, lr."""
    keys = jax.random.split(jax.random.key(seed), 5)
    normal = lambda i, shape, scale: scale * jax.random.normal(keys[i], shape)  # noqa: E731
    x = jax.nn.relu(normal(0, (n_layers, n, k), 1.0))
    d, p = normal(1, (n_layers, n, m), 1e-3), normal(2, (n_layers, k, m), 0.05)
    mu, nu = normal(3, (n_layers, k, m), 1e-3), jnp.abs(normal(4, (n_layers, k, m), 1e-6))
    bf16 = (a.astype(jnp.bfloat16) for a in (x, d, p, mu, nu))
    return (*bf16, jnp.int32(7), jnp.float32(1e-3))


def check(n_layers=2, n=200, k=72, m=40, config=(32, 16, 16, 4, 2)) -> dict:
    """The fused kernel's outputs against ``reference``: the largest difference, the share
    of equal entries and the reference's scale, per output."""
    args = operands(n_layers, n, k, m)
    got = pallas(*args, config=config, fused=True, interpret=jax.default_backend() != "gpu")
    out = {}
    for name, a, b in zip(("matrix", "m", "v", "norm rows"), got, reference(*args), strict=True):
        a, b = a.astype(jnp.float32), b.astype(jnp.float32)
        out[name] = dict(max_abs=float(jnp.max(jnp.abs(a - b))), equal=float(jnp.mean(a == b)),
                         scale=float(jnp.max(jnp.abs(b))))  # fmt: skip
    return out


def timed_us(f, args, calls=20) -> float:
    for _ in range(4):
        jax.block_until_ready(f(*args))
    start = time.perf_counter()
    for _ in range(calls):
        out = f(*args)
    jax.block_until_ready(out)
    return 1e6 * (time.perf_counter() - start) / calls


def _shape_rows(n_layers: int, k: int, m: int) -> list[dict]:
    args = operands(n_layers, BATCH, k, m)
    flop, rows = 2 * n_layers * BATCH * k * m, []

    def row(name, us, **extra):
        tflops = None if us is None else flop / us / 1e6
        rows.append(dict(layers=n_layers, shape=[k, m], name=name, us=us, tflops=tflops, **extra))
        print({key: v for key, v in rows[-1].items() if key != "error"}, flush=True)

    row("cublas_gemm", timed_us(jax.jit(lambda x, d: jnp.einsum("lnk,lnm->lkm", x, d)), args[:2]))
    for exact in (True, False):
        f = jax.jit(functools.partial(reference, exact=exact))
        row("xla_reference", timed_us(f, args), exact=exact)
    for config in CONFIGS:
        for fused, exact in ((False, True), (True, True), (True, False)):
            name = "pallas_fused" if fused else "pallas_gemm"
            f = jax.jit(functools.partial(pallas, config=config, fused=fused, exact=exact))
            try:
                row(name, timed_us(f, args if fused else args[:2]), config=list(config),
                    exact=exact)  # fmt: skip
            except Exception as e:  # noqa: BLE001 - a configuration that does not compile
                row(name, None, config=list(config), exact=exact,
                    error=traceback.format_exception_only(e)[-1][:400])  # fmt: skip
    return rows


def bench(n_layers: int) -> list[dict]:
    return [r for k, m in SHAPES for r in _shape_rows(n_layers, k, m)]


def report(result: dict, command: str) -> list[str]:
    best = {}
    for r in result["rows"]:
        key = (tuple(r["shape"]), r["name"], r.get("exact", True))
        if r["us"] is not None and (key not in best or r["us"] < best[key]["us"]):
            best[key] = r
    table = writing.markdown_table(
        ("matrix", "what", "rounding", "best tiles", "µs", "TFLOP/s of the GEMM"),
        [("×".join(map(str, k[0])), k[1],
          "" if k[1].endswith("gemm") else "stochastic" if k[2] else "nearest",
          ",".join(map(str, r.get("config", []))) or "cuBLAS", r["us"], r["tflops"])
         for k, r in best.items()],
        formats=("", "", "", "", ".1f", ".0f"),
        align="llllrr",
    )  # fmt: skip
    return [
        "# A weight gradient with Adam in its epilogue (Pallas) against cuBLAS and XLA's pass", "",
        f"{result['layers']} layers of batch {BATCH}, {result['device']}, jax {result['jax']}, "
        f"{result['date']}. Best of the tile configurations (`CONFIGS`) per row; every row in "
        "the JSON file.", "", *table, "", f"Command: `{command}`", "",
    ]  # fmt: skip


def main(argv=None) -> dict:
    args = writing.layers_parser(__doc__).parse_args(argv)
    result = dict(**measure.provenance(), layers=args.layers, check_small=check(), rows=[])
    print("check", result["check_small"], flush=True)
    if jax.default_backend() == "gpu":
        result["rows"] = bench(args.layers)
        for k, m in SHAPES:
            result[f"check_{k}x{m}"] = check(4, BATCH, k, m, CONFIGS[0])
    writing.publish_result(args.out, "bench_wgrad_adam", result, report)
    return result


if __name__ == "__main__":
    main()
