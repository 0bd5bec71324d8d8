"""``advisor-jax-car``: the car's runner, and with ``--sim`` the same runner without a car.

The runner (``advisor_jax/runner``) imports numpy only, so that it runs on the car's
computer; ``--sim`` needs the simulator (JAX, MuJoCo), which the runner may not import.
This entry point hands the runner the simulated car (``evaluation/sim_car.py``), imported
only when ``--sim`` is given: on the car, without JAX, everything else runs as before.
"""

from __future__ import annotations

import contextlib
import sys
from collections.abc import Sequence

from advisor_jax.runner.cli import main as runner_main


def simulated_car(args, policy):
    """The ``simulator`` of ``runner.cli.drive``: a ``SimulatedCar`` of policy.json's arena
    at the episode of ``--seed``."""
    try:
        with contextlib.redirect_stdout(sys.stderr):  # MJX's "Failed to import warp" notice
            from advisor_jax.evaluation.sim_car import SimulatedCar
    except ImportError as e:  # the car's own install: numpy only
        raise ValueError(
            f"--sim needs the simulator (JAX, MuJoCo: {e.name or e}), which this install "
            "lacks: run it where advisor-jax is fully installed"
        ) from None
    return SimulatedCar(policy, seed=args.seed)


def main(argv: Sequence[str] | None = None) -> int:
    return runner_main(argv, simulator=simulated_car)


if __name__ == "__main__":
    sys.exit(main())
