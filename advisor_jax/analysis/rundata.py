"""Kept run data: what a report needs of a run directory, small enough to commit.

``compact_run`` copies a finished run's JSON files (run.json, eval_seed<S>.json, command.json;
not eval.json or eval_episode<N>.json, whose evaluations run.json holds, except for a run
that stopped after writing eval.json) without indentation, the measured rates in them (the
evaluations, computed in float32) in float32's shortest digits (0.8100000619888306 → 0.81,
the same float32), run.json's agent rows without the hyperparameters at their default
and without its resume identity (``compact_json``), and its metrics.npz, compressed, with
float64 series stored as float32, the per-episode reward per step as float16 (within
2.5e-4; reports print fewer digits), the episode outcome and length as small integers and
the episode return left out (reward per step × length; ``with_derived`` restores it);
never params/, checkpoints/ (replay buffers), episodes.csv, train_log.jsonl (both already
in metrics.npz) or figures. ``runs.load_runs`` reads the result like any run directory.
"""

from __future__ import annotations

import io
import json
from pathlib import Path

import numpy as np

from advisor_jax.fileio import atomic_write_bytes, atomic_write_text

KEPT_JSON = ("run.json", "eval.json", "eval_episode*.json", "eval_seed*.json")
IN_RUN_JSON = ("eval.json", "eval_episode*.json")  # a finished run.json's evaluation(_at_episode)
DROPPED_KEYS = ("machine",)  # command.json: where a run ran, beyond its device
MEASURED_KEYS = ("evaluation", "evaluation_at_episode", "advisor_evaluation")  # of run.json


DERIVED = ("episode_return",)  # reward_per_step × length: ``with_derived`` rebuilds it
HALF = ("reward_per_step",)  # in [-1.1, 0.7]: float16, within 2.5e-4


def compact_metrics(arrays: dict[str, np.ndarray]) -> dict[str, np.ndarray]:
    """float64 → float32, the reward per step (``HALF``) → float16; outcome → int8 and
    length → int16 where they fit; the episode return left out where reward per step and
    length give it back."""
    out = {}
    derivable = "reward_per_step" in arrays and "length" in arrays
    for name, values in arrays.items():
        if name in DERIVED and derivable:
            continue
        if name in HALF and values.dtype in (np.float64, np.float32):
            values = values.astype(np.float16)
        elif values.dtype == np.float64:
            values = values.astype(np.float32)
        elif name in ("outcome", "phase") and values.size and np.abs(values).max() < 128:
            values = values.astype(np.int8)
        elif name == "length" and values.size and values.max() < 2**15:
            values = values.astype(np.int16)
        out[name] = values
    return out


def write_compact_json(path: Path, obj) -> None:
    """``obj`` as JSON without indentation (a run.json's per-agent rows: a third smaller)."""
    atomic_write_text(path, json.dumps(obj, separators=(",", ":")) + "\n")


def compact_json(name: str, record):
    """A kept JSON file's ``record`` with its float32 measurements in float32's shortest
    digits: every float of an eval*.json, and run.json's ``MEASURED_KEYS`` (not its
    settings, which are the user's float64 values). A run.json's agent rows leave out the
    hyperparameters at ``HParams``' default, which the loader reads back for a missing one
    (``point_settings.settings_of``; half of a kept run.json), and its ``identity`` (the
    sha256 of the full rows, which guards a resume; a kept copy is never resumed)."""
    if name.startswith("eval"):
        return float32_digits(record)
    if name == "run.json" and isinstance(record, dict):
        record = {k: v for k, v in record.items() if k != "identity"}
        if isinstance(record.get("agents"), list):
            record["agents"] = [_without_defaults(row) for row in record["agents"]]
        return {k: float32_digits(v) if k in MEASURED_KEYS else v for k, v in record.items()}
    return record


def _without_defaults(row: dict) -> dict:
    """An agent row without the hyperparameters equal to ``HParams``' default."""
    from advisor_jax.agent.hparams import HPARAM_DEFAULTS

    def default(key, value) -> bool:
        if key not in HPARAM_DEFAULTS or isinstance(value, bool):
            return False
        return isinstance(value, int | float) and float(value) == float(HPARAM_DEFAULTS[key])

    return {k: v for k, v in row.items() if not default(k, v)}


def float32_digits(value):
    """Floats (in any nesting of dicts and lists) as the shortest decimal of their float32:
    what kept copies store and what ``runs.load_runs`` reads an evaluation as, so that a
    kept copy (0.81) and the run itself (0.8100000619888306) give one answer, pooled,
    paired or compared seed by seed (a tie is a tie)."""
    if isinstance(value, dict):
        return {k: float32_digits(v) for k, v in value.items()}
    if isinstance(value, list):
        return [float32_digits(v) for v in value]
    if isinstance(value, float) and np.isfinite(value) and abs(value) < 3e38:
        return float(str(np.float32(value)))
    return value


def compact_run(src: Path, dest: Path) -> None:
    """The compact copy of run directory ``src`` in ``dest`` (module docstring)."""
    src, dest = Path(src), Path(dest)
    if src.resolve() == dest.resolve():
        raise ValueError(f"compact_run copies: {dest} must not be the run itself")
    dest.mkdir(parents=True, exist_ok=True)
    finished = json.loads((src / "run.json").read_text()).get("status") == "finished"
    for pattern in KEPT_JSON:
        if finished and pattern in IN_RUN_JSON:
            continue
        for path in src.glob(pattern):
            record = compact_json(path.name, json.loads(path.read_text()))
            write_compact_json(dest / path.name, record)
    if (src / "command.json").is_file():
        record = json.loads((src / "command.json").read_text())
        write_compact_json(
            dest / "command.json", {k: v for k, v in record.items() if k not in DROPPED_KEYS}
        )
    if (src / "metrics.npz").is_file():
        buf = io.BytesIO()
        np.savez_compressed(buf, **compact_metrics(dict(np.load(src / "metrics.npz"))))
        atomic_write_bytes(dest / "metrics.npz", buf.getvalue())


def with_derived(arrays: dict[str, np.ndarray]) -> dict[str, np.ndarray]:
    """``arrays`` with the series ``compact_metrics`` leaves out computed again (the episode
    return as reward per step × length, within length × 2.5e-4 of the recorded one; NaN
    for episodes not played)."""
    if "episode_return" not in arrays and {"reward_per_step", "length"} <= arrays.keys():
        per_step = arrays["reward_per_step"].astype(np.float32)
        arrays = {**arrays, "episode_return": per_step * arrays["length"]}
    return arrays
