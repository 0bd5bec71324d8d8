"""Shared fixtures of the runner tests: one exported actor per session (tests that tamper
with it copy it first). Helpers and hardware fakes live in ``runner_fakes.py``.
"""

from __future__ import annotations

import shutil

import jax
import numpy as np
import pytest
from runner_fakes import HIDDEN, asymmetric_actor_params, export_test_actor

from advisor_jax.agent.networks import make_actor
from advisor_jax.runner.policy import load_policy


@pytest.fixture(scope="session")
def actor_params():
    return asymmetric_actor_params()


@pytest.fixture(scope="session")
def jax_actor():
    """The JIT-compiled JAX actor at full float32 precision (the exporter's reference)."""
    apply = jax.jit(make_actor(HIDDEN).apply)

    def run(params, obs):
        with jax.default_matmul_precision("highest"):
            return np.asarray(apply(params, np.asarray(obs, np.float32)))

    return run


@pytest.fixture(scope="session")
def export_dir(tmp_path_factory, actor_params):
    out = tmp_path_factory.mktemp("export")
    export_test_actor(actor_params, out)
    return out


@pytest.fixture(scope="session")
def policy(export_dir):
    return load_policy(export_dir)


@pytest.fixture
def export_copy(export_dir, tmp_path):
    """A private copy of the export that a test may tamper with."""
    dst = tmp_path / "policy"
    shutil.copytree(export_dir, dst)
    return dst
