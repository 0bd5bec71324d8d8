"""Trains the TINY population of test_integrity.py on N forced CPU devices (a subprocess).

    python tests/train/devices_worker.py DEVICES full OUT        # a whole run
    python tests/train/devices_worker.py DEVICES interrupt OUT   # stop after chunk 1 (saved)
    python tests/train/devices_worker.py DEVICES resume OUT      # finish an interrupted run

XLA's CPU device count is fixed when JAX starts, so each device count needs its own process;
tests/train/test_devices.py runs this and compares the outputs with the one-device run.
"""

from __future__ import annotations

import os
import sys

DEVICES, MODE, OUT = int(sys.argv[1]), sys.argv[2], sys.argv[3]
os.environ["JAX_PLATFORMS"] = "cpu"
os.environ["XLA_FLAGS"] = (
    f"--xla_force_host_platform_device_count={DEVICES} --xla_backend_optimization_level=0"
)
sys.path.insert(0, os.path.join(os.path.dirname(__file__), "..", ".."))

import jax  # noqa: E402

from advisor_jax.training import reporting  # noqa: E402
from advisor_jax.training.host_loop import run_training  # noqa: E402
from tests.train.conftest import RUN_HP, RUN_SEEDS, TINY  # noqa: E402


def main() -> None:
    assert len(jax.devices()) == DEVICES, jax.devices()
    if MODE == "interrupt":
        real = reporting.chunk_line

        def chunk_line(step, *args):
            if step == TINY.chunk_steps:
                raise KeyboardInterrupt
            return real(step, *args)

        reporting.chunk_line = chunk_line
    kw = dict(eval_episodes=0, checkpoint_every=0, progress=False, devices=DEVICES)
    try:
        run_training(TINY, RUN_HP, {}, RUN_SEEDS, OUT, resume=MODE == "resume", **kw)
    except KeyboardInterrupt:
        assert MODE == "interrupt"


if __name__ == "__main__":
    main()
