"""XLA compile options for the jitted programs that hold a learner (issue 17).

``jax.jit(fn, compiler_options=compiler_options(cfg.precision, overlap=..., steady=...))``
is how the training chunk (``training.host_loop.population_functions``) and the learner
benchmarks compile. The options belong to one program, never to the process: a user's ``XLA_FLAGS``
and other jitted functions are left alone. CPUs get none (their programs are unchanged).

On GPUs, three settings, measured on one H100 (ATD3+AfDP, paper sizes, batch 1000, against
the commit before in the same command). The first two are for latency-bound programs only
(``overlap``: populations of at most ``host_loop.LATENCY_BOUND_AGENTS`` per GPU), because
they cost memory and gain nothing once the kernels fill the GPU:

* **Overlapping kernels** (``xla_gpu_command_buffer_scheduling_mode=CONCURRENT``): XLA runs
  a program's kernels as CUDA graphs, by default as one chain. A 1-agent training step is
  ~240 small kernels of ~2 µs (``results/profile_train/``), each using a few of the GPU's
  132 SMs; built by data dependence instead, the graph lets the independent ones run side
  by side (target and online critic passes, the advisor and the env beside the update).
  XLA then no longer reuses a buffer between kernels that may overlap: more memory.
* **Whole loops as graphs** (``xla_gpu_enable_command_buffer`` with ``WHILE``): only for
  programs without a ``lax.cond`` inside their loops (``steady``: the training chunk's
  steady program, ``training.train``; the learner benchmark's block loop). Then each scan
  runs as one graph, launched once, instead of one launch per step from the host.
  Together with the first: 1-agent bf16 training steps 1,939 → 3,536 agent env-steps/s
  (``results/bench_train_steady/``).
* **cuBLAS GEMMs for bf16** (``xla_gpu_enable_triton_gemm=False``): left free, XLA's
  autotuner hands the bf16 matmuls to Triton fusions that also carry the fp32 → bf16 casts
  and ReLUs; those ran the critic's [agents × 2, 1000, 500] GEMMs at 270 TFLOP/s of a
  measured 655 (``results/profile_learner_bf16/``). With cuBLAS GEMMs: learner 7,773 →
  10,345 agent-updates/s at 128 agents; 16 seeds each of ATD3+AfDP and DDPG learn as in
  fp32 (``results/bench_learner_cublas/``, ``results/precision_study.md``). fp32 learners
  keep XLA's default: cuBLAS already takes all their GEMMs
  (``results/bench_learner_relu_vjp.md``).
"""

from __future__ import annotations

import jax

CUBLAS_GEMMS = {"xla_gpu_enable_triton_gemm": False}
"""XLA debug options that leave every GEMM to cuBLAS (no Triton GEMM fusions)."""

OVERLAPPING_KERNELS = {"xla_gpu_command_buffer_scheduling_mode": "CONCURRENT"}
"""CUDA graphs built by data dependence: independent kernels may run at the same time."""

COMMAND_BUFFER_DEFAULTS = (
    "FUSION", "CUBLAS", "CUBLASLT", "CUSTOM_CALL", "CUDNN", "DYNAMIC_SLICE_FUSION", "CONDITIONAL"
)  # fmt: skip
"""What XLA records into CUDA graphs by default (``xla_gpu_enable_command_buffer``, jax
0.11.2's XLA); an option replaces the list, so ``WHOLE_LOOPS`` repeats it."""

WHOLE_LOOPS = {"xla_gpu_enable_command_buffer": ",".join((*COMMAND_BUFFER_DEFAULTS, "WHILE"))}
"""The defaults and while loops: a scan without conditionals inside runs as one graph."""


def compiler_options(
    precision: str, backend: str | None = None, overlap: bool = False, steady: bool = False
) -> dict[str, bool | str] | None:
    """``jax.jit``'s ``compiler_options`` for a program holding a ``precision`` learner
    (``AgentConfig.precision``) on ``backend`` (JAX's default when None). ``overlap``: a
    latency-bound program (a small population) whose kernels should overlap; ``steady``:
    also its loops hold no ``lax.cond``, so they run as whole graphs. None: XLA's defaults."""
    backend = jax.default_backend() if backend is None else backend
    if backend != "gpu":
        return None
    options: dict[str, bool | str] = {}
    if overlap:
        options.update(OVERLAPPING_KERNELS)
        if steady:
            options.update(WHOLE_LOOPS)
    if precision == "bf16":
        options.update(CUBLAS_GEMMS)
    return options or None
