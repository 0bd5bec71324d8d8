"""Experiment tracking beside the run directory, which stays the source of truth.

    tracker = make_tracker(tensorboard="tb/run1", wandb=None, name="run1", config=run_json)
    tracker.log_chunk(line)             # a train_log.jsonl row of advisor-jax's own agents
    tracker.log_agent(i, step, row)     # an epoch of brax agent i (seeds train one by one)
    tracker.close()

``--tensorboard DIR`` writes TensorBoard event files with tensorboardX (a dependency of
brax's, which brax's own ``brax.io.metrics.Writer`` uses too); ``--wandb PROJECT`` logs the
same scalars to Weights & Biases, importing ``wandb`` only then. Tags, x = environment
steps per agent:

    population/<metric>   mean over the agents of a chunk (what the progress bar shows)
    agent<i>/<metric>     agent i of run.json's "agents" (its seed and grid point)
    progress/episodes_mean, progress/episodes_min, progress/steps_per_second
"""

from __future__ import annotations

import math
from collections.abc import Mapping
from typing import Any

PROGRESS = ("episodes_mean", "episodes_min", "steps_per_second")


class Tracker:
    """Sends scalars to every backend (none: a tracker that does nothing)."""

    def __init__(self, backends: list | None = None):
        self.backends = backends or []

    def _send(self, scalars: Mapping[str, Any], step: int) -> None:
        finite = {
            tag: float(v)
            for tag, v in scalars.items()
            if isinstance(v, int | float) and not isinstance(v, bool) and math.isfinite(v)
        }
        for backend in self.backends:
            backend.log(finite, int(step))

    def log_chunk(self, line: Mapping[str, Any]) -> None:
        """A chunk of a population (``reporting.chunk_line``): means and per-agent values."""
        scalars = {f"progress/{k}": line[k] for k in PROGRESS if k in line}
        for name, value in line.items():
            if name in PROGRESS or name in ("step", "seconds", "per_agent"):
                continue
            scalars[f"population/{name}"] = value
        for name, values in line.get("per_agent", {}).items():
            scalars |= {f"agent{i}/{name}": v for i, v in enumerate(values)}
        self._send(scalars, line["step"])

    def log_agent(self, index: int, step: int, row: Mapping[str, Any]) -> None:
        """One agent's row (a brax epoch: episodes, seconds, brax's metrics)."""
        self._send({f"agent{index}/{k}": v for k, v in row.items() if k != "step"}, step)

    def close(self) -> None:
        for backend in self.backends:
            backend.close()


class TensorBoard:
    """Event files in ``logdir`` (tensorboardX)."""

    def __init__(self, logdir: str):
        from tensorboardX import SummaryWriter

        self.writer = SummaryWriter(logdir)

    def log(self, scalars: Mapping[str, float], step: int) -> None:
        for tag, value in scalars.items():
            self.writer.add_scalar(tag, value, step)
        self.writer.flush()

    def close(self) -> None:
        self.writer.close()


class WandB:
    """A Weights & Biases run in ``project`` (``wandb`` imported here only)."""

    def __init__(self, project: str, name: str, config: Mapping):
        try:
            import wandb
        except ImportError:
            raise ValueError(
                f"--wandb {project} needs the wandb package: pip install wandb (and wandb "
                "login), or leave --wandb out"
            ) from None
        self.run = wandb.init(project=project, name=name, config=dict(config))
        self.run.define_metric("env_step")
        self.run.define_metric("*", step_metric="env_step")

    def log(self, scalars: Mapping[str, float], step: int) -> None:
        self.run.log({**scalars, "env_step": step})

    def close(self) -> None:
        self.run.finish()


def make_tracker(tensorboard: str | None, wandb: str | None, name: str, config: Mapping) -> Tracker:
    """The tracker the options ask for (neither: one that does nothing)."""
    backends = []
    if tensorboard is not None:
        if not str(tensorboard).strip():
            raise ValueError("--tensorboard '' is empty: name the directory for event files")
        backends.append(TensorBoard(str(tensorboard)))
    if wandb is not None:
        if not wandb.strip():
            raise ValueError("--wandb '' is empty: name the Weights & Biases project")
        backends.append(WandB(wandb, name, config))
    return Tracker(backends)
