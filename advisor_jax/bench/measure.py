"""Where a number was measured, how it was timed and against which ceiling: one copy of each
for every benchmark in experiments/, so that every report is comparable with every other.

JAX is imported lazily and only where a function needs a device: the car runner's
benchmark (``bench_runner.py``) times a process that must never load it.
"""

from __future__ import annotations

import datetime
import functools
import json
import os
import platform
import subprocess
import sys
import tempfile
import time
from collections.abc import Callable, Sequence
from pathlib import Path
from typing import Any

import numpy as np


def cpu_name() -> str:
    """The CPU model ("Intel(R) Xeon(R) ..."): CPU-bound timings mean little without it."""
    try:
        with open("/proc/cpuinfo") as f:
            for line in f:
                if line.startswith("model name"):
                    return line.split(":", 1)[1].strip()
    except OSError:
        pass
    return platform.processor() or platform.machine()


def virtualisation() -> str:
    """ "KVM guest" and the like from lscpu's hypervisor line, "bare metal" when none: a VM's
    caches and speed are shared with its neighbours (bench_runner.md). Runs ``lscpu``, so it
    is not part of ``provenance()``."""
    try:
        out = subprocess.run(["lscpu"], capture_output=True, text=True, timeout=10).stdout
    except (OSError, subprocess.SubprocessError):
        return "unknown virtualisation"
    for line in out.splitlines():
        if line.startswith("Hypervisor vendor:"):
            return line.split(":", 1)[1].strip() + " guest"
    return "bare metal" if "cpu" in out.lower() else "unknown virtualisation"


MEMORY_SETTINGS = ("XLA_PYTHON_CLIENT_MEM_FRACTION", "XLA_PYTHON_CLIENT_PREALLOCATE",
                   "XLA_PYTHON_CLIENT_ALLOCATOR")  # fmt: skip
"""JAX's GPU memory settings (environment variables) a report records when set: they decide
how large a population fits."""


def provenance(with_jax: bool = True) -> dict[str, Any]:
    """Where and when a number was measured: one dict for every report that records one.

    ``date`` is the day this runs (not the day the code was written). With ``with_jax``
    also JAX's first device: ``backend`` (its platform, "cpu"/"gpu"), ``device`` (its kind,
    "NVIDIA H100 80GB HBM3") and the JAX version; without, JAX is not imported (the car
    runner's benchmarks time a process that never loads it)."""
    record: dict[str, Any] = {
        "date": datetime.date.today().isoformat(),
        "host": platform.node(),
        "cpu": cpu_name(),
        "cpu_count": os.cpu_count(),
        "python": platform.python_version(),
        "numpy": np.__version__,
    }
    if with_jax:
        import jax

        device = jax.devices()[0]
        record.update(backend=device.platform, device=device.device_kind, jax=jax.__version__)
        if os.environ.get("XLA_FLAGS"):  # a number measured under other flags says so
            record["xla_flags"] = os.environ["XLA_FLAGS"]
        memory = {k: os.environ[k] for k in MEMORY_SETTINGS if k in os.environ}
        if memory:  # and one measured with another share of the GPU's memory
            record["memory_settings"] = memory
    return record


# -- timers ---------------------------------------------------------------------------------


def _ready(out: Any) -> Any:
    """``out`` once computed: JAX dispatches asynchronously, so a timer that does not wait
    for the result times only the dispatch. Only when JAX is loaded: the car runner's
    benchmarks must not import it (and then nothing can be a JAX array)."""
    jax = sys.modules.get("jax")
    return out if jax is None else jax.block_until_ready(out)


def run_timed(fn: Callable[[], Any]) -> tuple[Any, float]:
    """``fn()``'s result (JAX arrays ready) and the wall-clock seconds it took."""
    t0 = time.perf_counter()
    out = _ready(fn())
    return out, time.perf_counter() - t0


def best_of(fn: Callable[[], Any], repeats: int) -> float:
    """Fastest of ``repeats`` calls of ``fn`` in seconds: the least disturbed by the machine.
    A ``fn`` whose inputs are donated must carry its state itself (e.g. in a closure)."""
    return min(run_timed(fn)[1] for _ in range(repeats))


def first_and_best(fn: Callable[[], Any], repeats: int) -> tuple[float, float]:
    """(seconds of the first call, which compiles; ``best_of`` the ``repeats`` after it)."""
    return run_timed(fn)[1], best_of(fn, repeats)


def per_call_us(
    cases: dict[str, Callable[[int], Any]],
    iters: int,
    warmup: int,
    pause: float = 0.0,
    before: Callable[[int], Any] | None = None,
) -> dict[str, np.ndarray]:
    """Wall-clock µs of every call of every case (each called with the call's index), the
    cases interleaved call by call: latency distributions (p50, p99), not a best time.
    ``pause`` (s): sleep before each round, as the car's control loop sleeps between cycles;
    ``before(i)``: an untimed call after the sleep (the loop's warm-up)."""
    for i in range(warmup):
        for fn in cases.values():
            fn(i)
    times = {name: np.empty(iters) for name in cases}
    wall_ns, sleep = time.perf_counter_ns, time.sleep
    for i in range(iters):
        if pause:
            sleep(pause)
        if before is not None:
            before(warmup + i)
        for name, fn in cases.items():
            t0 = wall_ns()
            fn(warmup + i)
            times[name][i] = (wall_ns() - t0) / 1e3
    return times


# -- ceilings: what the device can do at all, measured in the same process as the timings ---


CHAIN = 20
"""Dependent matmuls per timed call of ``matmul_ceiling``."""


def default_chain() -> int:
    """``matmul_ceiling``'s chain where none is given: ``CHAIN`` on an accelerator, 1 on a CPU,
    where one 8192² product takes seconds and the chain would take minutes for nothing (a
    dispatch is nothing beside it)."""
    import jax

    return 1 if jax.default_backend() == "cpu" else CHAIN


def chain_operands(n: int, dtype: Any) -> tuple[Any, Any]:
    """(a, c) of ``chained_matmuls``, ``n``×``n`` in ``dtype``: ``a`` with entries of variance
    1/n, so that the products keep their scale."""
    import jax

    a = (jax.random.normal(jax.random.PRNGKey(0), (n, n)) / n**0.5).astype(dtype)
    return a, jax.random.normal(jax.random.PRNGKey(1), (n, n)).astype(dtype)


def chained_matmuls(a: Any, c: Any, steps: int) -> Any:
    """``a`` to the power ``steps`` times ``c``, one product after another in a ``fori_loop``:
    each product reads the one before, so none can be skipped, hoisted or run beside another."""
    import jax

    return jax.lax.fori_loop(0, steps, lambda _, x: a @ x, c)


def matmul_ceiling(
    n: int, repeats: int = 5, dtype: Any = "float32", chain: int | None = None
) -> float:
    """FLOP/s of ``n``×``n`` matmuls, fp32 at JAX's default precision (TF32 on recent NVIDIA
    GPUs) or ``dtype="bfloat16"``: the rate a dense network could sustain on this device,
    this run. Timed as ``chain`` dependent products in one jitted loop (``chained_matmuls``),
    the best of ``repeats`` calls after a compiling one, so that the GPU runs them back to
    back as a training loop runs its GEMMs, with one dispatch and one wait per ``chain``
    products (``chain_operands``; None: ``default_chain``).

    Until 2026-11-28 the ceiling was one product per call (``chain=1``). On an H100 that read
    bf16 639–711 TFLOP/s within one process and 633–723 between processes, against 699–739
    for 20 products a call; fp32 336–371 against 355–358 (``results/bench_ceiling/``)."""
    import jax

    chain = default_chain() if chain is None else chain
    a, c = chain_operands(n, dtype)
    products = jax.jit(functools.partial(chained_matmuls, steps=chain))
    return 2 * n**3 * chain / first_and_best(lambda: products(a, c), repeats)[1]


def copy_ceiling(n_bytes: int, repeats: int = 5) -> float:
    """Bytes/s read plus written by a device-to-device copy of ``n_bytes`` of fp32: the
    best of a plain copy and an elementwise add (one read, one write each), since
    either can be the faster kernel. The data is random, not constant."""
    import jax

    x = jax.random.uniform(jax.random.PRNGKey(1), (n_bytes // 4,))
    kernels = (jax.jit(lambda a: a + 1.0), jax.jit(lambda a: a.copy()))
    seconds = min(first_and_best(functools.partial(f, x), repeats)[1] for f in kernels)
    return 2 * x.nbytes / seconds


# -- the numbers before a change, measured in the same command ------------------------------


def run_reference(tree: str | os.PathLike, script: str, argv: Sequence[str], report: str) -> dict:
    """The JSON report ``report`` of ``experiments/<script>`` of the checkout ``tree`` (e.g.
    the commit before a speed change: ``git worktree add /tmp/ref HEAD~1``, or an untracked
    copy of it beside this checkout), run with ``argv`` and its own
    ``--out`` in a subprocess whose imports resolve to ``tree``: the previous numbers come
    from the same machine and the same minute as the new ones."""
    tree = Path(tree).resolve()  # the subprocess runs in tree/experiments: a relative tree breaks
    path = tree / "experiments" / script
    if not path.exists():
        raise SystemExit(f"--reference {tree}: no experiments/{script} there")
    with tempfile.TemporaryDirectory() as out:
        subprocess.run(
            [sys.executable, str(path), *argv, "--out", out],
            check=True,
            env=checkout_env(tree),
            cwd=path.parent,
        )
        return json.loads((Path(out) / report).read_text())


def checkout_env(tree: str | os.PathLike) -> dict[str, str]:
    """This process's environment with ``PYTHONPATH`` led by the checkout ``tree`` and without
    this checkout: a subprocess started with it imports ``tree``'s ``advisor_jax`` when its
    working folder is not on its import path (a folder outside this checkout, or ``python
    -P``: ``paired_trees.py``)."""
    here = Path(__file__).resolve().parents[2]  # this checkout
    paths = [p for p in os.environ.get("PYTHONPATH", "").split(os.pathsep) if p]
    paths = [str(Path(tree).resolve())] + [p for p in paths if Path(p).resolve() != here]
    return {**os.environ, "PYTHONPATH": os.pathsep.join(paths)}
