"""The XLA compile options of programs that hold a learner (training/compiler.py).

On GPUs a latency-bound program (a small population) overlaps independent kernels, and one
without conditionals in its loops (``steady``) also runs them as whole CUDA graphs; a bf16
learner compiles its GEMMs to cuBLAS; CPUs keep XLA's defaults. The options must be names
and values XLA knows (a misspelt one fails every GPU compile), and the training chunk must
be compiled with the options of its learner's precision and program.
"""

from __future__ import annotations

import dataclasses
import os
import subprocess
import sys

import jax
import jax.numpy as jnp
import pytest

from advisor_jax.agent.config import HParams
from advisor_jax.training import program
from advisor_jax.training.compiler import (
    CUBLAS_GEMMS,
    OVERLAPPING_KERNELS,
    SEPARATE_OUTPUTS,
    WHOLE_LOOPS,
    compiler_options,
)
from advisor_jax.training.devices import place
from advisor_jax.training.population import agent_keys, build_population
from tests.training.conftest import TINY


@pytest.mark.parametrize(
    ("precision", "backend", "overlap", "steady", "expected"),
    [("bf16", "gpu", False, False, CUBLAS_GEMMS), ("fp32", "gpu", False, False, CUBLAS_GEMMS),
     ("fp32", "gpu", True, False, OVERLAPPING_KERNELS),  # a small baseline population
     ("fp32", "gpu", True, True, {**OVERLAPPING_KERNELS, **WHOLE_LOOPS}),
     ("bf16", "gpu", True, True, {**OVERLAPPING_KERNELS, **WHOLE_LOOPS, **CUBLAS_GEMMS}),
     ("fp32", "gpu", False, True, CUBLAS_GEMMS),  # whole loops only where kernels overlap
     ("bf16", "cpu", True, True, None), ("fp32", "cpu", False, False, None),
     ("bf16", "tpu", True, True, None)],
)  # fmt: skip
def test_gpu_programs_get_their_options_and_others_none(
    precision, backend, overlap, steady, expected
):
    assert compiler_options(precision, backend, overlap, steady) == expected
    separate = compiler_options(precision, backend, overlap, steady, separate=True)
    assert separate == (None if expected is None else {**expected, **SEPARATE_OUTPUTS})


def test_only_the_latency_bound_program_of_one_or_two_bf16_agents_separates_outputs():
    assert program.separates_outputs("latency-bound", "bf16", 1)
    assert program.separates_outputs("latency-bound", "bf16", 2)
    others = [("latency-bound", "bf16", 3), ("latency-bound", "bf16", 8),
              ("latency-bound", "bf16", 64), ("latency-bound", "bf16", None),
              ("latency-bound", "fp32", 1), ("steady", "bf16", 1),
              ("general", "bf16", 1)]  # fmt: skip
    assert not any(program.separates_outputs(*args) for args in others)


def test_separate_outputs_keep_the_passes_xla_flags_disable(monkeypatch):
    monkeypatch.setenv("XLA_FLAGS", "--xla_force_host_platform_device_count=2 "
                       "--xla_disable_hlo_passes=algsimp,cse")  # fmt: skip
    options = compiler_options("bf16", "gpu", True, True, separate=True)
    assert options["xla_disable_hlo_passes"] == "algsimp,cse,multi_output_fusion"
    monkeypatch.delenv("XLA_FLAGS")
    assert compiler_options("bf16", "gpu", True, True, separate=True)["xla_disable_hlo_passes"] == (
        "multi_output_fusion"
    )


PROGRAM_LIST_REPLACES_FLAGS = """
import jax, jax.numpy as jnp
f = jax.jit(lambda x: jnp.exp(x) * jnp.sin(x) + 1.0, compiler_options=OPTIONS)
print(f.lower(jnp.ones(8)).compile().as_text().count("kind=kLoop"))
"""


@pytest.mark.parametrize("options", [None, {"xla_disable_hlo_passes": "multi_output_fusion"}])
def test_a_programs_disabled_passes_replace_the_process_flags(options):
    # Why compiler_options prepends XLA_FLAGS' passes: with fusion disabled by the process's
    # flags a CPU program has a kernel per op (5), unless its own list replaces the flags' (1).
    env = {**os.environ, "XLA_FLAGS": "--xla_disable_hlo_passes=fusion", "JAX_PLATFORMS": "cpu"}
    code = PROGRAM_LIST_REPLACES_FLAGS.replace("OPTIONS", repr(options))
    out = subprocess.run([sys.executable, "-c", code], env=env, capture_output=True, text=True)
    assert out.returncode == 0, out.stderr
    assert int(out.stdout.split()[-1]) == (5 if options is None else 1)


def test_whole_loop_graphs_keep_what_xla_records_by_default():
    # The option replaces XLA's list: losing FUSION or CUBLAS would take kernels out of graphs.
    recorded = WHOLE_LOOPS["xla_gpu_enable_command_buffer"].split(",")
    assert {"FUSION", "CUBLAS", "CUBLASLT", "CONDITIONAL", "WHILE"} <= set(recorded)


def test_the_gpu_options_are_compile_options_xla_knows():
    # XLA checks every option's name whatever the backend: an unknown one raises here too.
    options = compiler_options("bf16", "gpu", overlap=True, steady=True)
    f = jax.jit(lambda x: x @ x, compiler_options=options)
    assert float(f(jnp.eye(4))[0, 0]) == 1.0
    with pytest.raises(Exception, match="not a valid enum value"):
        jax.jit(lambda x: x, compiler_options={**options, **{k: "BOGUS" for k in WHOLE_LOOPS}})(
            jnp.eye(4)
        )
    with pytest.raises(Exception, match="No such compile option"):
        jax.jit(lambda x: x @ x, compiler_options={"xla_no_such_option": True})(jnp.eye(4))


def test_the_training_chunk_compiles_with_its_learners_options(monkeypatch):
    asked = []

    def options(precision, backend=None, overlap=False, steady=False, separate=False):
        asked.append((precision, overlap, steady, separate))  # XLA rejects the name below:
        return {"xla_no_such_option_for_this_test": True}  # proof the chunk got it

    monkeypatch.setattr(program, "compiler_options", options)
    cfg = dataclasses.replace(TINY, agent=dataclasses.replace(TINY.agent, precision="bf16"))
    for name in ("general", "steady"):  # XLA's scheduling: no overlapping kernels
        program.population_functions(cfg, program=name)
    for agents in (3, 1):  # one (or two) agents per device: its outputs separate
        program.population_functions(cfg, place(agents, 1), "latency-bound")
    _, init_fn, chunk_fn = program.population_functions(cfg, program="latency-bound")
    assert asked == [("bf16", False, False, False), ("bf16", False, True, False),
                     ("bf16", True, True, False), ("bf16", True, True, True),
                     ("bf16", True, True, False)]  # fmt: skip
    hp, _ = build_population(HParams(), {}, seeds=[0])
    state = init_fn(agent_keys([0]))  # init keeps XLA's defaults
    with pytest.raises(Exception, match="No such compile option"):
        chunk_fn.lower(state, hp, jnp.int32(0)).compile()
