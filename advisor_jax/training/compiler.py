"""The XLA options a program holding a learner is compiled with (``jax.jit``'s
``compiler_options``): one program's options, chosen by ``training/program.py`` for the
training chunk and by ``bench/learner_loop.py`` for the learner benchmark. A user's
``XLA_FLAGS`` and other jitted functions are left alone; CPUs get XLA's defaults.
"""

from __future__ import annotations

import os
import re

import jax

CUBLAS_GEMMS = {"xla_gpu_enable_triton_gemm": False}
"""XLA debug options that leave every GEMM to cuBLAS (no Triton GEMM fusions)."""

OVERLAPPING_KERNELS = {"xla_gpu_command_buffer_scheduling_mode": "CONCURRENT"}
"""CUDA graphs built by data dependence: independent kernels may run at the same time."""

SEPARATE_OUTPUTS = {"xla_disable_hlo_passes": "multi_output_fusion"}
"""XLA's multi-output fusion off (``program.separates_outputs``). It had put the update's
minibatch draw into a kernel of the collection's noise (both read the step's key split), so
each update waited for its step's collection (``results/bench_separate_outputs/``)."""

COMMAND_BUFFER_DEFAULTS = (
    "FUSION", "CUBLAS", "CUBLASLT", "CUSTOM_CALL", "CUDNN", "DYNAMIC_SLICE_FUSION", "CONDITIONAL"
)  # fmt: skip
"""What XLA records into CUDA graphs by default (``xla_gpu_enable_command_buffer``, jax
0.11.2's XLA); an option replaces the list, so ``WHOLE_LOOPS`` repeats it."""

WHOLE_LOOPS = {"xla_gpu_enable_command_buffer": ",".join((*COMMAND_BUFFER_DEFAULTS, "WHILE"))}
"""The defaults and while loops: a scan without conditionals inside runs as one graph."""


def compiler_options(
    precision: str,
    backend: str | None = None,
    overlap: bool = False,
    steady: bool = False,
    separate: bool = False,
) -> dict[str, bool | str] | None:
    """``jax.jit``'s ``compiler_options`` for a program holding a ``precision`` learner on
    ``backend`` (JAX's default when None); None: XLA's defaults (every CPU program). They
    belong to one program: a user's ``XLA_FLAGS`` and other jitted functions are left alone.

    On GPUs:

    * ``overlap`` (a latency-bound program, ``program.latency_bound``):
      ``OVERLAPPING_KERNELS``. XLA's CUDA graphs, by default one chain, built by data
      dependence: a 1-agent step's small independent kernels (critic passes, advisor, env)
      run side by side; buffers are no longer reused between kernels that may overlap: more
      memory.
    * ``steady`` too (the program's loops hold no ``lax.cond``: the chunk's steady program,
      the learner benchmark's block loop): ``WHOLE_LOOPS``, each scan one graph launched
      once instead of one launch per step (``results/bench_train_steady/``).
    * bf16: ``CUBLAS_GEMMS``. XLA's autotuner gave the bf16 matmuls to Triton fusions far
      slower than cuBLAS (``results/profile_learner_bf16/``, ``results/bench_learner_cublas/``).
    * ``separate`` (``program.separates_outputs``): ``SEPARATE_OUTPUTS``, after the passes that
      ``XLA_FLAGS`` disables (a program's list replaces the process's).
    * fp32, but for the latency-bound program (not measured so): ``CUBLAS_GEMMS`` too. The
      autotuner gave a held target critic's GEMM to Triton; the 128-agent fp32 learner ran
      1.03× faster on cuBLAS (``results/bench_first_layer_kernel/``).
    """
    backend = jax.default_backend() if backend is None else backend
    if backend != "gpu":
        return None
    options: dict[str, bool | str] = {}
    if overlap:
        options.update(OVERLAPPING_KERNELS)
        if steady:
            options.update(WHOLE_LOOPS)
    if precision == "bf16" or not overlap:
        options.update(CUBLAS_GEMMS)
    if separate:
        options.update(SEPARATE_OUTPUTS)
    if passes := options.get("xla_disable_hlo_passes"):
        user = re.findall(r"--xla_disable_hlo_passes=(\S+)", os.environ.get("XLA_FLAGS", ""))
        options["xla_disable_hlo_passes"] = ",".join((*user, passes))
    return options or None
