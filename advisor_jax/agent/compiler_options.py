"""XLA compile options for the jitted programs that hold a learner (issue 17).

``jax.jit(fn, compiler_options=compiler_options(cfg.precision))`` is how the training chunk
(``training.host_loop.population_functions``) and the learner benchmarks compile. The
options belong to one program, never to the process: a user's ``XLA_FLAGS`` and other jitted
functions are left alone.

bf16 learners on GPUs compile their GEMMs to cuBLAS, not to XLA's Triton GEMM emitter
(``xla_gpu_enable_triton_gemm=False``). Left free, XLA's autotuner hands the bf16 matmuls
to Triton fusions that also carry the fp32 → bf16 casts and ReLUs; those ran the critic's
[agents × 2, 1000, 500] GEMMs at 270 TFLOP/s of a measured 655
(``results/profile_learner_bf16/``). With cuBLAS GEMMs and the twin critics' inputs per
critic (``networks.inputs_per_critic_by_default``), on one H100 against the commit before in
the same command (ATD3+AfDP, paper sizes, batch 1000, 2026-11-25,
``results/bench_learner_cublas/``): learner 7,773 → 10,345 agent-updates/s at 128 agents
(+33 %), 2,654 → 2,963 at 1; full training step 7,237 → 9,342 agent env-steps/s at 64 agents
(+29 %). 16 seeds each of ATD3+AfDP and DDPG learn as in fp32 (``results/precision_study.md``).

fp32 learners keep XLA's default: cuBLAS already takes all their GEMMs
(``results/bench_learner_relu_vjp.md``), and handing them to Triton ran no faster
(``results/bench_learner_xla_flags/``). CPUs have no Triton emitter; their
programs are unchanged (no options).
"""

from __future__ import annotations

import jax

CUBLAS_GEMMS = {"xla_gpu_enable_triton_gemm": False}
"""XLA debug options that leave every GEMM to cuBLAS (no Triton GEMM fusions)."""


def compiler_options(precision: str, backend: str | None = None) -> dict[str, bool] | None:
    """``jax.jit``'s ``compiler_options`` for a program holding a ``precision`` learner
    (``AgentConfig.precision``) on ``backend`` (JAX's default when None); None: XLA's
    defaults."""
    backend = jax.default_backend() if backend is None else backend
    if backend == "gpu" and precision == "bf16":
        return dict(CUBLAS_GEMMS)
    return None
