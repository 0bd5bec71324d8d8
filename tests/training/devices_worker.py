"""Trains the TINY population of tests/training/conftest.py on N forced CPU devices (a subprocess).

    python tests/training/devices_worker.py DEVICES MODE=OUT [MODE=OUT ...] [PROCESS_ID PORT]

MODE is ``full`` (a whole run), ``interrupt`` (stop after the first chunk, checkpoint saved)
or ``resume`` (finish an interrupted run); the runs share one compiled program. With
PROCESS_ID and PORT the process is one of two of a jax.distributed job on localhost
(coordinator 127.0.0.1:PORT) and DEVICES counts its local devices. XLA's CPU device count is
fixed when JAX starts, so each device count needs its own process; tests/training/
test_devices.py runs this and compares the outputs with the one-device run.
"""

from __future__ import annotations

import os
import sys

DEVICES = int(sys.argv[1])
RUNS = [tuple(arg.split("=", 1)) for arg in sys.argv[2:] if "=" in arg]
rest = [arg for arg in sys.argv[2:] if "=" not in arg]
PROCESS = (int(rest[0]), rest[1]) if rest else None
os.environ["JAX_PLATFORMS"] = "cpu"
# The suite's compile flags (tests/conftest.py), which the test passes on, and the devices.
os.environ["XLA_FLAGS"] = (
    os.environ.get("XLA_FLAGS", "--xla_backend_optimization_level=0")
    + f" --xla_force_host_platform_device_count={DEVICES}"
)
sys.path.insert(0, os.path.join(os.path.dirname(__file__), "..", ".."))

import jax  # noqa: E402

from advisor_jax.training import reporting  # noqa: E402
from advisor_jax.training.devices import initialize_distributed, place  # noqa: E402
from advisor_jax.training.host_loop import run_training  # noqa: E402
from advisor_jax.training.program import population_functions  # noqa: E402
from tests.training.conftest import RUN_HP, RUN_SEEDS, TINY  # noqa: E402


def main() -> None:
    if PROCESS is not None:
        process_id, port = PROCESS
        initialize_distributed(f"127.0.0.1:{port}", 2, process_id)
    assert len(jax.local_devices()) == DEVICES, jax.local_devices()
    devices = len(jax.devices())
    program = population_functions(TINY, place(len(RUN_SEEDS), devices))
    real = reporting.chunk_line
    for mode, out in RUNS:

        def chunk_line(step, *args, mode=mode):
            if mode == "interrupt" and step == TINY.chunk_steps:
                raise KeyboardInterrupt
            return real(step, *args)

        reporting.chunk_line = chunk_line
        kw = dict(eval_episodes=0, checkpoint_every=0, progress=False, devices=devices)
        try:
            run_training(
                TINY, RUN_HP, {}, RUN_SEEDS, out, resume=mode == "resume", program=program, **kw
            )
        except KeyboardInterrupt:
            assert mode == "interrupt"


if __name__ == "__main__":
    main()
