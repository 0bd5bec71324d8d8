"""Suite-wide test settings. Per-area fixtures live in tests/<area>/conftest.py."""

import os

# CPU only, and quiet about optional GPU back ends; set before jax is imported.
os.environ.setdefault("JAX_PLATFORMS", "cpu")
os.environ.setdefault("XLA_PYTHON_CLIENT_PREALLOCATE", "false")
# The suite is dominated by XLA compiles of small programs. At backend optimisation level 0
# they compile ~30 % faster and the suite runs ~20 % faster. Without LLVM's expensive passes
# two heavy test files run another ~4 % faster (55.3 -> 53.0 s and 57.7 -> 55.0 s). With
# XLA's older elemental emitters instead of its MLIR fusion emitters, test_lfd.py and
# test_env_motion_mjx.py take 89 instead of 125 CPU-seconds (2-core AMD EPYC VM, jax 0.10.2).
# Numerics stay IEEE fp32, but two programs that compute the same sums may round them apart
# (tests/compare.py compares such runs); production runs keep XLA's defaults. A flag this
# jaxlib does not know would abort XLA, so the emitters' flag is tried once, in a child
# process, by the first process of the session (pytest-xdist's workers inherit the result).
_FLAGS = ("--xla_backend_optimization_level=0", "--xla_llvm_disable_expensive_passes=true")
_EMITTERS = "--xla_cpu_use_fusion_emitters=false"


def _xla_accepts(flags: str) -> bool:
    import subprocess
    import sys

    probe = "import jax.numpy as jnp; jnp.zeros(1).block_until_ready()"
    env = {**os.environ, "XLA_FLAGS": flags}
    return (
        subprocess.run([sys.executable, "-c", probe], env=env, capture_output=True).returncode == 0
    )


for _flag in _FLAGS:
    if _flag.split("=")[0] not in os.environ.get("XLA_FLAGS", ""):
        os.environ["XLA_FLAGS"] = (os.environ.get("XLA_FLAGS", "") + " " + _flag).strip()
if "xla_cpu_use_fusion_emitters" not in os.environ["XLA_FLAGS"]:
    _with = f"{os.environ['XLA_FLAGS']} {_EMITTERS}"
    if _xla_accepts(_with):
        os.environ["XLA_FLAGS"] = _with

# One persistent compilation cache for the session, inherited by the subprocesses the tests
# start: a worker that compiles a program some earlier process compiled (the 2-device TINY
# chunk of tests/training/collectives_worker.py and devices_worker.py) loads it instead.
# Fresh per session (nothing carries over between runs) and removed when the session ends.
if "JAX_COMPILATION_CACHE_DIR" not in os.environ:
    import atexit
    import shutil
    import tempfile

    _cache = tempfile.mkdtemp(prefix="advisor-jax-test-xla-")
    atexit.register(shutil.rmtree, _cache, ignore_errors=True)
    os.environ["JAX_COMPILATION_CACHE_DIR"] = _cache
    os.environ.setdefault("JAX_PERSISTENT_CACHE_MIN_COMPILE_TIME_SECS", "1")

# Property tests explore new examples on every developer run, but CI replays a fixed
# derandomised set: a submission's CI result must not depend on what Hypothesis drew.
from hypothesis import settings  # noqa: E402

settings.register_profile("ci", derandomize=True)
if os.environ.get("CI"):
    settings.load_profile("ci")
