"""The XLA compile options of programs that hold a learner (agent/compiler_options.py).

A bf16 learner on a GPU compiles its GEMMs to cuBLAS; everything else keeps XLA's defaults.
The options must be names XLA knows (a misspelt one fails every bf16 GPU compile), and the
training chunk must be compiled with the options of its learner's precision.
"""

from __future__ import annotations

import dataclasses

import jax
import jax.numpy as jnp
import pytest

from advisor_jax.agent.compiler_options import CUBLAS_GEMMS, compiler_options
from advisor_jax.agent.config import HParams
from advisor_jax.training import host_loop
from advisor_jax.training.population import agent_keys, build_population
from tests.train.conftest import TINY


@pytest.mark.parametrize(
    ("precision", "backend", "expected"),
    [("bf16", "gpu", CUBLAS_GEMMS), ("fp32", "gpu", None), ("bf16", "cpu", None),
     ("fp32", "cpu", None), ("bf16", "tpu", None)],
)  # fmt: skip
def test_only_bf16_learners_on_gpus_leave_their_gemms_to_cublas(precision, backend, expected):
    assert compiler_options(precision, backend) == expected


def test_the_gpu_options_are_compile_options_xla_knows():
    # XLA checks every option's name whatever the backend: an unknown one raises here too.
    f = jax.jit(lambda x: x @ x, compiler_options=compiler_options("bf16", "gpu"))
    assert float(f(jnp.eye(4))[0, 0]) == 1.0
    with pytest.raises(Exception, match="No such compile option"):
        jax.jit(lambda x: x @ x, compiler_options={"xla_no_such_option": True})(jnp.eye(4))


def test_the_training_chunk_compiles_with_its_learners_options(monkeypatch):
    asked = []

    def options(precision, backend=None):  # a name XLA rejects: proof the chunk got it
        asked.append(precision)
        return {"xla_no_such_option_for_this_test": True}

    monkeypatch.setattr(host_loop, "compiler_options", options)
    cfg = dataclasses.replace(TINY, agent=dataclasses.replace(TINY.agent, precision="bf16"))
    _, init_fn, chunk_fn = host_loop.population_functions(cfg)
    assert asked == ["bf16"]
    hp, _ = build_population(HParams(), {}, seeds=[0])
    state = init_fn(agent_keys([0]))  # init keeps XLA's defaults
    with pytest.raises(Exception, match="No such compile option"):
        chunk_fn.lower(state, hp, jnp.int32(0)).compile()
