"""JSON-lines log of the control loop: one header, one record per cycle, one footer.

Schema (every line is one JSON object with a ``type``)::

    {"type": "header", "schema": 1, "policy_dir", "weights_sha256", "config_hash", "goal",
     "observation": ObservationConfig fields, "drive": Drive.describe(), "loop": LoopConfig
     fields, "created", "numpy", "argv"}
    {"type": "cycle", "i", "t" (loop clock, s), "wall" (time.time()), "ran" (the controller
     ran; false when a source failed), "state" ("run" | "stop" | "done"), "reason", "message",
     "scan": {"stamp", "n", "points"?}, "pose": {"x", "y", "theta", "t", "stamp"},
     "obs" [20], "action" [V, ω], "physical" [v m/s, w rad/s], "command" {"kind", ...},
     "io_error", "compute_ms" (from reading the sources to the motor command, ms),
     "warm_ms" (the warm-up pass before it, ms; null without LoopConfig.warm_up)}
    {"type": "footer", "cycles", "stops" {reason: count}, "overruns", "end"}

A scan's ``points`` (the raw RPLIDAR triples) are written the first time the loop uses that
scan; later cycles that reuse it carry only its ``stamp``. Floats are written with Python's
shortest round-trip repr, so a replay reads back bit-identical inputs and float32 values.
"""

from __future__ import annotations

import datetime
import json
import os
import time
from collections.abc import Iterator
from typing import IO, Any

import numpy as np

from advisor_jax.fileio import create_exclusive
from advisor_jax.runner.errors import ReplayError
from advisor_jax.runner.observation import Pose, Scan

LOG_SCHEMA = 1


def floats(values: Any) -> list[float] | None:
    """float32/float64 array → list of Python floats (exact), or None."""
    return None if values is None else [float(v) for v in np.asarray(values).reshape(-1)]


def encode_scan(scan: Scan | None, with_points: bool) -> dict | None:
    if scan is None:
        return None
    out: dict[str, Any] = {"stamp": float(scan.stamp), "n": int(len(scan.points))}
    if with_points:
        try:
            out["points"] = np.asarray(scan.points, dtype=np.float64).tolist()
        except (TypeError, ValueError):
            out["points"] = repr(scan.points)  # unusable scan: logged for the human reader
    return out


def encode_pose(pose: Pose | None) -> dict | None:
    if pose is None:
        return None
    return {"x": pose.x, "y": pose.y, "theta": pose.theta, "t": pose.t, "stamp": pose.stamp}


def decode_pose(rec: dict | None) -> Pose | None:
    if rec is None:
        return None
    return Pose(rec["x"], rec["y"], rec["theta"], rec["t"], rec["stamp"])


class JsonlLog:
    """Line-buffered JSONL writer; each line is flushed so a crash loses at most one cycle.
    A path must name a new file (``fileio.create_exclusive``): an existing log, an export's
    policy.npz or a link is never written over."""

    def __init__(self, path: str | os.PathLike | IO[str]):
        if hasattr(path, "write"):
            self._f, self._own = path, False
            self.path = getattr(path, "name", None)
        else:
            self._f, self._own = create_exclusive(path), True
            self.path = os.fspath(path)

    def write(self, record: dict) -> None:
        self._f.write(json.dumps(record, allow_nan=True, separators=(",", ":")) + "\n")
        self._f.flush()

    def close(self) -> None:
        if self._own and not self._f.closed:
            self._f.flush()
            os.fsync(self._f.fileno())
            self._f.close()


def new_log(path: str | None, prefix: str) -> JsonlLog:
    """A log in a new file: ``path``, or ``<prefix>-<UTC time>.jsonl`` (with a suffix if
    another run of the same second took that name). Never over an existing file."""
    if path is not None:
        return JsonlLog(path)
    stamp = datetime.datetime.now(datetime.UTC).strftime("%Y%m%d-%H%M%S")
    for n in range(100):
        try:
            return JsonlLog(f"{prefix}-{stamp}{'' if n == 0 else f'-{n}'}.jsonl")
        except FileExistsError:
            continue
    raise OSError(f"cannot create a log {prefix}-{stamp}-*.jsonl: every name is taken")


def read_log(path: str | os.PathLike) -> tuple[dict, Iterator[dict]]:
    """(header, iterator over cycle records) of a loop log; ReplayError if unreadable."""
    try:
        with open(path, encoding="utf-8") as f:
            lines = [line for line in f if line.strip()]
    except OSError as e:
        raise ReplayError(f"{path}: cannot read log ({e.strerror or e})") from None
    except UnicodeDecodeError as e:  # a ValueError that would not name the file
        raise ReplayError(
            f"{path}: not a loop log (not UTF-8 text: byte {e.start} is {e.object[e.start]:#04x})"
        ) from None
    records = []
    for number, line in enumerate(lines, 1):
        try:
            record = json.loads(line)
        except json.JSONDecodeError as e:
            if number == len(lines):
                break  # the last line of a log cut off by a crash or power loss
            raise ReplayError(f"{path}:{number}: not JSON ({e})") from None
        if not isinstance(record, dict):
            raise ReplayError(f"{path}:{number}: not a JSON object ({type(record).__name__})")
        records.append(record)
    if not records or records[0].get("type") != "header":
        raise ReplayError(f"{path}: first line is not a loop log header")
    if records[0].get("schema") != LOG_SCHEMA:
        raise ReplayError(f"{path}: log schema {records[0].get('schema')!r} is not {LOG_SCHEMA}")
    return records[0], (r for r in records[1:] if r.get("type") == "cycle")


def cycle_record(
    i, now, scan, pose, result, ran, io_error, *, with_points, compute_ms, warm_ms
) -> dict:
    """One control cycle's line of the log (``run_loop`` writes it after each cycle)."""
    return {
        "type": "cycle",
        "i": i,
        "t": now,
        "wall": time.time(),
        "ran": ran,
        "state": result.state,
        "reason": result.reason,
        "message": result.message,
        "scan": encode_scan(scan, with_points),
        "pose": encode_pose(pose),
        "obs": floats(result.obs),
        "action": floats(result.action),
        "physical": None if result.physical is None else list(result.physical),
        "command": None if result.command is None else result.command.as_dict(),
        "io_error": io_error,
        "compute_ms": compute_ms,
        "warm_ms": warm_ms,
    }


def log_header(controller: Any, policy: Any, argv: list[str] | None = None) -> dict:
    """The log's first line: what replay needs, plus provenance."""
    meta = getattr(policy, "meta", {})
    return {
        "type": "header",
        "schema": LOG_SCHEMA,
        "policy_dir": os.path.abspath(policy.directory) if hasattr(policy, "directory") else None,
        "weights_sha256": meta.get("weights_sha256"),
        "config_hash": meta.get("config_hash"),
        "created": datetime.datetime.now(datetime.UTC).isoformat(timespec="seconds"),
        "numpy": np.__version__,
        "argv": list(argv) if argv is not None else None,
        **controller.describe(),
    }
