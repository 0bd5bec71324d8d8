"""Do Pallas's Mosaic GPU GEMMs keep cuBLAS's pace on the critics' weight-gradient shapes?

Moving Adam's pass into the weight gradient's epilogue needs a GEMM that takes an epilogue
and runs at cuBLAS's speed (``bench_wgrad_adam.py``: Pallas's Triton GEMM ran at a third of
it). Pallas's other GPU backend, Mosaic GPU, issues Hopper's wgmma and TMA instructions; JAX
ships GEMMs written with it in ``jax.experimental.pallas.ops.gpu``. This probe times two of
them, as JAX ships them, against cuBLAS (XLA's dot, Triton GEMMs off), in one process:

* ``cublas_wgrad``: ``xᵀ d`` for ``--layers`` layers (64 agents' twin critics: 128), bf16
  out, at the paper's shapes (batch 1000; matrices 1008×504 and 504×608) and at the same
  shapes padded to multiples of 64 (batch 1024; 1024×512 and 512×640);
* ``mosaic_wgrad``: the same product as ``transposed_ragged_dot_mgpu`` (the weight gradient
  of a grouped matmul, one group per layer, the batch rows of all layers stacked; it needs
  the matrix's sides to be multiples of its tiles, so the padded shapes only), per tile
  configuration (``WGRAD_TILES``);
* ``cublas_matmul`` and ``mosaic_matmul``: one large GEMM ``a @ b`` and the warp-specialized
  ``hopper_matmul_mgpu`` (``MATMUL_TILES``), the backend's best case.

    python experiments/probe_mosaic_gemm.py --out OUT          # on an H100: the table
    python experiments/probe_mosaic_gemm.py --out /tmp         # CPU: the check only

Every run first checks both kernels against XLA's product on small operands (the Mosaic GPU
interpreter off a GPU). Writes ``--out``/``probe_mosaic_gemm.json`` and ``.md``.
"""

from __future__ import annotations

import functools
import time
import traceback
import types

import jax
import jax.numpy as jnp

from advisor_jax.bench import measure, writing

WGRAD_SHAPES = ((1000, 1008, 504), (1000, 504, 608), (1024, 1024, 512), (1024, 512, 640))
"""(batch, matrix rows, matrix columns): the paper's two large critic matrices, then padded."""
WGRAD_TILES = ((64, 128, 64, 4, 1), (128, 128, 64, 4, 1), (128, 64, 64, 4, 1),
               (64, 256, 64, 3, 1), (128, 256, 64, 3, 1), (128, 128, 64, 6, 4))  # fmt: skip
"""``transposed_ragged_dot``: (block_m, block_n, block_k, max_concurrent_steps, grid_block_n)."""
MATMUL_SHAPES = ((4096, 4096, 4096), (8192, 4096, 1024), (1024, 512, 1024))
"""(m, n, k) of ``a [m, k] @ b [k, n]``."""
MATMUL_TILES = ((128, 128, 4, "N"), (128, 64, 4, "N"), (64, 128, 4, "M"), (128, 256, 3, "M"))
"""``hopper_matmul_mgpu.TuningConfig``: (tile_m, tile_n, max_concurrent_steps, wg_dimension)."""


def _interpret():
    """Mosaic GPU's interpreter (JAX's, not public API) off a GPU; None on a GPU."""
    if jax.default_backend() == "gpu":
        return None
    from jax._src.pallas.mosaic_gpu.interpret.params import InterpretGPUParams

    return InterpretGPUParams()


def _on_cpu(module, cores: int):
    """``module`` (one of JAX's Mosaic GPU kernels) with every ``plgpu.kernel`` it builds run
    by the interpreter and ``cores`` standing in for the GPU's SMs; itself on a GPU."""
    interpret = _interpret()
    if interpret is None:
        return module
    plgpu = types.SimpleNamespace(**vars(module.plgpu))
    plgpu.kernel = functools.partial(module.plgpu.kernel, interpret=interpret)
    gpu = types.SimpleNamespace(core_count=cores)  # what the kernels ask of a device
    jax_ = types.SimpleNamespace(**{**vars(jax), "devices": lambda: [gpu]})
    names = dict(vars(module))
    for name, f in vars(module).items():
        if isinstance(f, types.FunctionType) and f.__globals__ is vars(module):
            names[name] = types.FunctionType(f.__code__, names, name, f.__defaults__, f.__closure__)
    names.update(plgpu=plgpu, jax=jax_, get_num_sms=lambda: cores)
    return types.SimpleNamespace(**names)


def wgrad_reference(x: jax.Array, d: jax.Array) -> jax.Array:
    """``xᵀ d`` per layer: ``[L, n, k] × [L, n, m] → [L, k, m]``, bf16 out."""
    return jnp.einsum("lnk,lnm->lkm", x, d)


def mosaic_wgrad(x: jax.Array, d: jax.Array, tiles, cores: int = 132) -> jax.Array:
    """``wgrad_reference`` as ``transposed_ragged_dot_mgpu``: one group per layer."""
    from jax.experimental.pallas.ops.gpu import transposed_ragged_dot_mgpu as module

    (layers, n, k), m = x.shape, d.shape[2]
    bm, bn, bk, steps, grid_n = tiles
    kernel = _on_cpu(module, cores).transposed_ragged_dot
    sizes = jnp.full((layers,), n, jnp.int32)
    return kernel(x.reshape(layers * n, k), d.reshape(layers * n, m), group_sizes=sizes,
                  block_m=bm, block_n=bn, block_k=bk, max_concurrent_steps=steps,
                  grid_block_n=grid_n)  # fmt: skip


def mosaic_matmul(a: jax.Array, b: jax.Array, tiles, cores: int = 132) -> jax.Array:
    """``a @ b`` as ``hopper_matmul_mgpu``, bf16 out."""
    from jax.experimental.pallas.ops.gpu import hopper_matmul_mgpu as module

    tm, tn, steps, wg = tiles
    config = module.TuningConfig(
        tile_m=tm, tile_n=tn, tile_k=64, max_concurrent_steps=steps,
        wg_dimension=module.MatmulDimension[wg], grid_tile_width=4,
    )  # fmt: skip
    return _on_cpu(module, cores).matmul(a, b, None, config)


def operands(shape_a, shape_b, seed=0):
    ka, kb = jax.random.split(jax.random.key(seed))
    return (jax.random.normal(ka, shape_a, jnp.bfloat16),
            jax.random.normal(kb, shape_b, jnp.bfloat16))  # fmt: skip


def relative_error(got: jax.Array, want: jax.Array) -> float:
    """Largest difference over the largest entry of ``want``, in fp32."""
    got, want = got.astype(jnp.float32), want.astype(jnp.float32)
    return float(jnp.max(jnp.abs(got - want)) / jnp.max(jnp.abs(want)))


def check() -> dict:
    """The kernels against XLA on small operands: the matmul everywhere; the weight gradient
    on a GPU only (the interpreter has no rule for its masks' ``layout_cast``), with a ragged
    batch of 100 rows, not a multiple of the 64-row blocks, as the paper's 1000 is not."""
    a, b = operands((256, 128), (128, 256), seed=1)
    out = dict(matmul=relative_error(mosaic_matmul(a, b, (64, 64, 2, "N"), cores=2), a @ b))
    if jax.default_backend() == "gpu":
        x, d = operands((2, 100, 128), (2, 100, 64))
        out["wgrad"] = relative_error(mosaic_wgrad(x, d, (64, 64, 64, 2, 1)), wgrad_reference(x, d))
    return out


def timed_us(f, args, calls=30, repeats=3) -> float:
    """Best of ``repeats`` means over ``calls`` back-to-back calls, in µs."""
    jax.block_until_ready(f(*args))
    best = float("inf")
    for _ in range(repeats):
        start = time.perf_counter()
        for _ in range(calls):
            out = f(*args)
        jax.block_until_ready(out)
        best = min(best, (time.perf_counter() - start) / calls)
    return 1e6 * best


CUBLAS = {"xla_gpu_enable_triton_gemm": False}


def _timed_rows(kind, shape, flop, xla, mosaic, args, tile_set, fits) -> list[dict]:
    rows = []

    def row(name, us, error=None, **extra):
        tflops = None if us is None else flop / us / 1e6
        rows.append(dict(kind=kind, shape=list(shape), name=name, us=us, tflops=tflops,
                         error=error, **extra))  # fmt: skip
        print({k: v for k, v in rows[-1].items() if k != "error"}, flush=True)

    want = jax.jit(xla, compiler_options=CUBLAS)
    row(f"cublas_{kind}", timed_us(want, args))
    reference = want(*args)
    for tiles in tile_set:
        if not fits(tiles):
            continue
        f = jax.jit(functools.partial(mosaic, tiles=tiles))
        try:
            us = timed_us(f, args)
            row(f"mosaic_{kind}", us, tiles=list(tiles),
                relative_error=relative_error(f(*args), reference))  # fmt: skip
        except Exception as e:  # noqa: BLE001 - a tile configuration that does not compile
            row(f"mosaic_{kind}", None, tiles=list(tiles),
                error=traceback.format_exception_only(e)[-1][:400])  # fmt: skip
    return rows


def bench(layers: int) -> list[dict]:
    rows = []
    for n, k, m in WGRAD_SHAPES:
        args = operands((layers, n, k), (layers, n, m))
        fits = lambda t, k=k, m=m: k % t[0] == 0 and m % t[1] == 0  # noqa: E731
        rows += _timed_rows("wgrad", (layers, n, k, m), 2 * layers * n * k * m, wgrad_reference,
                            mosaic_wgrad, args, WGRAD_TILES, fits)  # fmt: skip
    for m, n, k in MATMUL_SHAPES:
        args = operands((m, k), (k, n))
        rows += _timed_rows("matmul", (m, n, k), 2 * m * n * k, jnp.matmul, mosaic_matmul, args,
                            MATMUL_TILES, lambda t: True)  # fmt: skip
    return rows


def report(result: dict, command: str) -> list[str]:
    best: dict = {}
    for r in result["rows"]:
        key = (r["kind"], tuple(r["shape"]), r["name"].split("_")[0])
        if r["us"] is not None and (key not in best or r["us"] < best[key]["us"]):
            best[key] = r
    lines = []
    for (kind, shape, backend), r in best.items():
        cublas = best.get((kind, shape, "cublas"))
        ratio = None if backend == "cublas" or cublas is None else cublas["us"] / r["us"]
        tiles = ",".join(map(str, r.get("tiles", [])))
        lines.append((kind, "×".join(map(str, shape)), backend, tiles, r["us"], r["tflops"], ratio))
    table = writing.markdown_table(
        ("GEMM", "shape", "backend", "best tiles", "µs", "TFLOP/s", "speed of cuBLAS's"),
        lines, formats=("", "", "", "", ".1f", ".0f", ".2f"), align="lllllrr",
    )  # fmt: skip
    return [
        "# Mosaic GPU GEMMs (JAX's own) against cuBLAS", "",
        f"{result['device']}, jax {result['jax']}, {result['date']}. wgrad shape: layers × "
        "batch × matrix rows × matrix columns; matmul: m × n × k. Best tile configuration per "
        "row; every row in the JSON file. Checks against XLA, relative: "
        f"{result['check_small']}.", "", *table, "", f"Command: `{command}`", "",
    ]  # fmt: skip


def main(argv=None) -> dict:
    args = writing.layers_parser(__doc__).parse_args(argv)
    result = dict(**measure.provenance(), layers=args.layers, check_small=check(), rows=[])
    print("check", result["check_small"], flush=True)
    if jax.default_backend() == "gpu":
        result["rows"] = bench(args.layers)
    writing.publish_result(args.out, "probe_mosaic_gemm", result, report)
    return result


if __name__ == "__main__":
    main()
