"""Fixtures of the export tests: the runner tests' exported actor (tests/runner/conftest.py
and its helpers in runner_fakes.py), shared rather than written twice."""

from __future__ import annotations

import sys
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "runner"))  # runner_fakes

from tests.runner.conftest import actor_params, export_dir, jax_actor, policy  # noqa: E402, F401
