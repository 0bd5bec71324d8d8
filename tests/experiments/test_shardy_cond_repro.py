"""experiments/shardy_cond_repro.py (the small program for an upstream report on the GPU
compile's all-gathers) runs and reads its own HLO; on forced CPU devices it finds nothing in
the loop, as the CPU compile of the training chunk does."""

from __future__ import annotations

import os
import subprocess
import sys
from pathlib import Path

SCRIPT = Path(__file__).resolve().parents[2] / "experiments" / "shardy_cond_repro.py"


def test_the_repro_compiles_on_two_cpu_devices_and_lists_the_loops_collectives():
    env = {k: v for k, v in os.environ.items() if k != "XLA_FLAGS"}
    done = subprocess.run([sys.executable, str(SCRIPT), "--agents", "4", "--width", "32"],
                          env=env, capture_output=True, text=True, timeout=300)  # fmt: skip
    assert done.returncode == 0, done.stderr[-2000:]
    assert "2 cpu devices, Shardy: 0 collective(s) inside the loop" in done.stdout
