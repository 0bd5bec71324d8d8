"""A run directory's record and identity: what ``run.json`` may hold, which run a saved
file belongs to, and whether a directory is exactly one run.

* ``read_run_json(path)``: run.json as a dict whose every field a reader uses has the
  right type, or ValueError naming the file and the field (``[1, 2, 3]``, ``null``, a
  string for ``agents`` ... reached ``AttributeError`` tracebacks).
* ``run_identity(config, agents, advisor)``: ``{"config_sha256", "seeds"}``, the sha256 of
  the canonical JSON of the run's config, agents (seeds and hyperparameters) and advisor
  (its spec and the sha256 of its parameters, ``training/advisor_source``; runs of older
  versions have none) and the seeds themselves. run.json, every checkpoint's and the
  final parameters' ``sha256.json`` carry it (``checkpoint``), so a file copied from another
  run, or one left by a killed run whose run.json was removed, is refused instead of mixed
  in; a run whose advisor changed is not resumed (``check_same_advisor``); one resumed
  on another device, jax or ``XLA_FLAGS`` is, with a warning (``compiled_by``).
* ``check_new_directory(out_dir)``: a fresh run needs an empty directory (``.lock`` aside):
  a killed run's checkpoints or log would otherwise be taken for the new run's.
* ``check_run_entries(out_dir)``: the files of a run are not links (a resumed run writes
  them), and its directories are directories.
"""

from __future__ import annotations

import hashlib
import json
import math
import os
from pathlib import Path
from typing import Any

STATUSES = ("running", "interrupted", "finished")
RUN_FILES = (
    "run.json",
    "train_log.jsonl",
    "metrics.npz",
    "episodes.csv",
    "eval.json",
    "learning_curve.png",
    "diagnostics.png",
)
RUN_DIRECTORIES = ("checkpoints", "params")
LOCK_FILE = ".lock"


def canonical_sha256(obj: Any) -> str:
    """sha256 of the canonical JSON of ``obj`` (sorted keys, no spaces)."""
    text = json.dumps(obj, sort_keys=True, separators=(",", ":"), ensure_ascii=True)
    return hashlib.sha256(text.encode("ascii")).hexdigest()


def run_identity(config: dict, agents: list[dict], advisor: dict | None = None) -> dict:
    """The identity of a run: sha256 of its config, agents and advisor record (as run.json
    holds them; no advisor: a run of an older version), and its seeds (readable in
    messages)."""
    record = {"config": config, "agents": agents}
    if advisor is not None:
        record["advisor"] = advisor
    plain = json.loads(json.dumps(record))  # tuples -> lists
    return {
        "config_sha256": canonical_sha256(plain),
        "seeds": [int(a["seed"]) for a in plain["agents"]],
    }


def describe_identity(identity: Any) -> str:
    """'seeds [0, 1], config 1a2b3c4d5e6f…' for messages."""
    if not isinstance(identity, dict):
        return f"{identity!r}"
    digest = str(identity.get("config_sha256", "?"))[:12]
    return f"seeds {identity.get('seeds')}, config {digest}…"


def _problem(path: Path, what: str) -> ValueError:
    return ValueError(f"{path} is not a usable run record: {what}")


def _load_json(path: Path) -> Any:
    try:
        data = path.read_bytes()
    except IsADirectoryError:
        raise _problem(path, "it is a directory") from None
    except FileNotFoundError:
        raise ValueError(f"{path.parent} is not a training run (no run.json)") from None
    except OSError as e:
        raise OSError(f"cannot read {path}: {e.strerror or e}") from None
    try:
        return json.loads(data.decode("utf-8"))
    except UnicodeDecodeError as e:
        raise _problem(path, f"not UTF-8 text (byte {e.start})") from None
    except json.JSONDecodeError as e:
        raise ValueError(f"{path} is corrupt: {e}") from None
    except RecursionError:
        raise _problem(path, "its JSON is nested too deeply") from None


def read_run_json(path: str | os.PathLike) -> dict:
    """run.json, checked: every field that resume, export and evaluate read has its type."""
    path = Path(path)
    record = _load_json(path)
    if not isinstance(record, dict):
        raise _problem(path, f"it holds a JSON {type(record).__name__}, not an object")
    if not isinstance(record.get("config"), dict):
        raise _problem(path, f"config is {_kind(record.get('config'))}, not an object")
    agents = record.get("agents")
    if not isinstance(agents, list) or not agents:
        raise _problem(path, f"agents is {_kind(agents)}, not a non-empty list")
    for i, agent in enumerate(agents):
        if not isinstance(agent, dict):
            raise _problem(path, f"agents[{i}] is {_kind(agent)}, not an object")
        seed = agent.get("seed")
        if isinstance(seed, bool) or not isinstance(seed, int) or not 0 <= seed < 2**64:
            raise _problem(path, f"agents[{i}].seed is {seed!r}, not a seed")
        if agent.get("index", i) != i:
            raise _problem(path, f"agents[{i}].index is {agent.get('index')!r}, not {i}")
    status = record.get("status")
    if status not in STATUSES:
        raise _problem(path, f"status is {status!r}, not one of {', '.join(STATUSES)}")
    diverged = record.get("diverged", [])
    if not isinstance(diverged, list) or not all(
        type(i) is int and 0 <= i < len(agents) for i in diverged
    ):
        raise _problem(path, f"diverged is {diverged!r}, not a list of agent indices")
    for key, kinds in (
        ("evaluation", dict),
        ("grid", dict),
        ("identity", dict),
        ("advisor", dict),
        ("created", str),
        ("train_seconds", int | float),
    ):
        value = record.get(key)
        if value is not None and (isinstance(value, bool) or not isinstance(value, kinds)):
            raise _problem(path, f"{key} is {_kind(value)}")
    seconds = record.get("train_seconds")
    if seconds is not None and not (math.isfinite(seconds) and seconds >= 0):
        raise _problem(path, f"train_seconds is {seconds!r}")
    identity = record.get("identity")
    if identity is not None and identity != run_identity(
        record["config"], agents, record.get("advisor")
    ):
        raise _problem(
            path,
            f"its identity ({describe_identity(identity)}) does not match its own config, "
            "agents and advisor (run.json was edited, or pieced together from two runs)",
        )
    return record


def _kind(value: Any) -> str:
    return "missing" if value is None else f"a JSON {type(value).__name__} ({value!r:.40})"


def check_directory(out_dir: Path, resume: bool) -> None:
    """A run's directory before it writes anything: a new run's must be empty (``.lock``
    aside), a resumed run's files must not be links (``check_run_entries``)."""
    if resume:
        check_run_entries(out_dir)
        return
    if (out_dir / "run.json").exists():
        raise ValueError(
            f"{out_dir} already holds a run; pass --resume to continue it or choose another --out"
        )
    check_new_directory(out_dir)


def resume_record(run_file: Path, summary: dict) -> dict:
    """run.json of the run being resumed, checked (``read_run_json``) and compared with the
    ``summary`` these options give: ValueError naming the fields that differ. Carries over
    into ``summary`` what the run keeps (its creation time; no identity if it was started
    by a version that recorded none)."""
    saved = read_run_json(run_file)
    current = json.loads(json.dumps({"config": summary["config"], "agents": summary["agents"]}))
    if "advisor" not in saved["config"] and saved.get("kind") != "brax":  # brax: no advisor
        if saved["status"] != "finished":
            raise ValueError(
                f"cannot resume {run_file.parent}: it was started by a version before plug-in "
                "advisors, whose checkpoints lack the advisor's state; train it anew"
            )
        current["config"].pop("advisor", None)  # finished: nothing is resumed
    found = differences({k: saved.get(k) for k in current}, current)
    if found:
        raise ValueError(
            f"cannot resume {run_file.parent}: its config or agents differ from these: "
            + "; ".join(found)
        )
    check_same_advisor(saved.get("advisor"), summary.get("advisor"), run_file.parent)
    if "identity" not in saved:
        summary.pop("identity", None)
    summary["created"] = saved.get("created", summary["created"])
    return saved


def check_same_advisor(saved: dict | None, current: dict | None, run_dir: Path) -> None:
    """Refuses to resume a run whose advisor (run.json's ``advisor``: spec, kind, sha256 of
    its parameters and of a function's source) differs from the one it was trained with."""
    if saved is None or current is None:
        return
    names = {"spec": "name", "kind": "kind", "params_sha256": "parameters",
             "source_sha256": "function's source"}  # fmt: skip
    for key, what in names.items():
        if saved.get(key) != current.get(key):
            raise ValueError(
                f"cannot resume {run_dir}: its advisor's {what} changed since it started "
                f"(run.json: {str(saved.get(key))[:16]}, now: {str(current.get(key))[:16]}); "
                f"restore advisor {saved.get('spec')!r} as it was, or train a new run"
            )


COMPILED_BY = {"device": "device", "jax": "jax", "xla_flags": "XLA_FLAGS"}
"""run.json's record of what compiled the run's programs (key: name in a message)."""


def compiled_by(saved: dict, summary: dict) -> list[str]:
    """What compiled the run being resumed (``saved``) that is not what compiles it now
    (``summary``): the device, jax and ``XLA_FLAGS`` (``COMPILED_BY``), one line each, e.g.
    ``"jax '0.10.2' → '0.11.2'"``. Other kernels may compute other roundings, so the resumed
    run need not repeat an unbroken one bit for bit. A field a run does not record (older
    versions) is not compared."""
    return [
        f"{name} {saved[key]!r} → {summary.get(key)!r}"
        for key, name in COMPILED_BY.items()
        if key in saved and saved[key] != summary.get(key)
    ]


def differences(saved, current, path: str = "") -> list[str]:
    """Where two JSON values differ: 'config.episodes: run.json has 60, these options give
    25', one entry per differing leaf (the first 5, then a count)."""
    out: list[str] = []
    if isinstance(saved, dict) and isinstance(current, dict):
        for key in sorted(set(saved) | set(current)):
            where = f"{path}.{key}" if path else key
            if key not in saved or key not in current:
                side = "run.json lacks it" if key not in saved else "these options lack it"
                out.append(f"{where}: {side}")
            else:
                out += differences(saved[key], current[key], where)
    elif isinstance(saved, list) and isinstance(current, list) and len(saved) == len(current):
        for i, (a, b) in enumerate(zip(saved, current, strict=True)):
            out += differences(a, b, f"{path}[{i}]")
    elif saved != current:
        out.append(f"{path}: run.json has {saved!r}, these options give {current!r}")
    if not path and len(out) > 5:
        out = out[:5] + [f"and {len(out) - 5} more"]
    return out


def check_new_directory(out_dir: Path) -> None:
    """A new run's directory must be empty but for a lock file: anything else belongs to
    another run (a killed run whose run.json was removed) or to someone else."""
    try:
        entries = sorted(set(os.listdir(out_dir)) - {LOCK_FILE})
    except FileNotFoundError:
        return
    if entries:
        more = f" and {len(entries) - 5} more" if len(entries) > 5 else ""
        shown = ", ".join(entries[:5]) + more
        raise ValueError(
            f"{out_dir} is not empty ({shown}) and holds no run.json: a new run needs a new or "
            "empty directory (files of another run would be mixed into this one); choose "
            "another --out"
        )


def check_run_entries(out_dir: Path) -> None:
    """Refuses a run directory whose files are links or of the wrong kind: a resumed run
    writes them, and must not write through a link it did not make."""
    for name in (*RUN_FILES, *RUN_DIRECTORIES, LOCK_FILE):
        path = out_dir / name
        if path.is_symlink():
            raise ValueError(
                f"{path} is a symbolic link; a run never writes through a link it did not "
                "make: replace it by the file itself, or remove it"
            )
        if not path.exists():
            continue
        if name in RUN_DIRECTORIES and not path.is_dir():
            raise ValueError(f"{path} should be a directory; it is not")
        if name not in RUN_DIRECTORIES and not path.is_file():
            raise ValueError(f"{path} should be a regular file; it is not")
