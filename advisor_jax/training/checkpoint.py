"""Checkpoints with orbax: atomic, restorable, with clear errors on missing or corrupt data.

* ``save_step(dir, step, state)`` / ``restore_latest(dir, abstract_state)``: periodic full
  training state through an orbax ``CheckpointManager`` (each step is written to a
  temporary directory and committed by rename, so a crash never leaves a half-written
  checkpoint; the two newest are kept).
* ``save_tree(path, tree)`` / ``load_tree(path)``: one pytree (the final parameters).

Checksums. Orbax checks neither: one flipped bit in a saved array changes a weight and is
restored silently (or marks a healthy agent as diverged). So every save also writes
``sha256.json`` inside the saved directory, the sha256 of each of its files, and every load
verifies it first (``verify_checksums``). ``restore_latest`` skips a checkpoint that fails
the check (or that orbax cannot read), restores the newest good one, moves the bad ones
aside as ``<step>.corrupt`` (so the resumed run can save that step again) and reports it;
``load_tree`` refuses corrupt parameters. A directory saved before checksums were recorded
(or whose save was killed between orbax's commit and the manifest) loads unverified, with
a warning. Errors are one line: orbax/TensorStore messages are cut to their first line.
"""

from __future__ import annotations

import hashlib
import json
import shutil
import warnings
from collections.abc import Callable
from pathlib import Path
from typing import Any

import jax
import jax.numpy as jnp
import numpy as np
import orbax.checkpoint as ocp

from advisor_jax.fileio import atomic_write_json

_KEEP = 2
CHECKSUMS = "sha256.json"
_MAX_MESSAGE = 200


class ChecksumError(ValueError):
    """A saved directory's files differ from the checksums recorded when it was saved."""


def _file_sha256(path: Path) -> str:
    with open(path, "rb") as f:
        return hashlib.file_digest(f, "sha256").hexdigest()


def record_checksums(directory: str | Path) -> Path:
    """Writes ``directory/sha256.json``: the sha256 of every file below ``directory``."""
    directory = Path(directory)
    files = {
        path.relative_to(directory).as_posix(): _file_sha256(path)
        for path in sorted(directory.rglob("*"))
        if path.is_file() and path.name != CHECKSUMS
    }
    return atomic_write_json(directory / CHECKSUMS, {"algorithm": "sha256", "files": files})


def verify_checksums(directory: str | Path) -> bool:
    """True if every file recorded in ``directory/sha256.json`` is present and unchanged;
    False if no checksums were recorded (an older save); ChecksumError naming the first
    bad file otherwise. Files added after the save are ignored (orbax never adds any)."""
    directory = Path(directory)
    manifest = directory / CHECKSUMS
    if not manifest.is_file():
        return False
    try:
        files = json.loads(manifest.read_text())["files"]
        items = sorted(files.items())
    except (ValueError, KeyError, TypeError, AttributeError) as e:
        raise ChecksumError(f"{manifest} is corrupt ({type(e).__name__}: {e})") from None
    for name, expected in items:
        path = directory / name
        if not path.is_file():
            raise ChecksumError(f"{path} is missing (recorded in {CHECKSUMS} at save time)")
        actual = _file_sha256(path)
        if actual != expected:
            raise ChecksumError(
                f"{path} has sha256 {actual[:12]}…, not the {str(expected)[:12]}… recorded "
                "when it was saved (the file was modified or damaged)"
            )
    return True


def _short(e: BaseException) -> str:
    """First line of an exception's message, cut to a readable length (TensorStore's run to
    kilobytes of JSON)."""
    text = str(e).strip().splitlines()[0] if str(e).strip() else ""
    text = text if len(text) <= _MAX_MESSAGE else text[:_MAX_MESSAGE] + "…"
    return f"{type(e).__name__}: {text}" if text else type(e).__name__


def _warn(message: str) -> None:
    warnings.warn(message, stacklevel=3)


def _manager(directory: Path) -> ocp.CheckpointManager:
    directory = directory.absolute()
    directory.mkdir(parents=True, exist_ok=True)  # orbax's create=True needs every process
    return ocp.CheckpointManager(
        directory,
        options=ocp.CheckpointManagerOptions(
            max_to_keep=_KEEP, create=False, multiprocessing_options=_this_process_only()
        ),
    )


def _this_process_only() -> ocp.options.MultiprocessingOptions:
    """Checkpoints hold host (numpy) copies and are read and written by one process (the
    run's writer, process 0 of a multi-host job): orbax must not wait for the others."""
    index = jax.process_index()
    return ocp.options.MultiprocessingOptions(primary_host=index, active_processes={index})


def _storable(tree: Any) -> dict[str, Any]:
    """Leaves by flattened index, without the zero-size ones orbax refuses to store."""
    leaves = jax.tree_util.tree_leaves(tree)
    return {f"{i:04d}": leaf for i, leaf in enumerate(leaves) if leaf.size}


def _rebuild(stored: dict[str, Any], abstract: Any) -> Any:
    """Inverse of ``_storable`` given the tree structure: empty leaves are recreated.

    Every leaf comes back as an uncommitted array, like the output of a fresh ``init``:
    orbax returns a mix of committed and uncommitted arrays, and jit keys its cache on
    that, so a resumed run would otherwise recompile its chunk function.
    """
    leaves, treedef = jax.tree_util.tree_flatten(abstract)
    full = [
        _uncommitted(stored[f"{i:04d}"]) if leaf.size else jnp.zeros(leaf.shape, leaf.dtype)
        for i, leaf in enumerate(leaves)
    ]
    return jax.tree_util.tree_unflatten(treedef, full)


def _uncommitted(x) -> jax.Array:
    return jnp.asarray(np.asarray(x))


def save_step(directory: str | Path, step: int, state: Any) -> None:
    """Saves the full training state at environment step ``step`` (blocking), then records
    its checksums.

    If a checkpoint of ``step`` exists already, nothing is written: the run is at the step it
    just saved or resumed from, so the state is that checkpoint's (an interrupt right after a
    periodic save, or before the first chunk after a resume, used to fail on orbax's
    "Checkpoint for step N already exists").
    """
    with _manager(Path(directory)) as manager:
        if int(step) in manager.all_steps():
            return
        manager.save(int(step), args=ocp.args.StandardSave(_storable(state)), force=True)
        manager.wait_until_finished()
    record_checksums(Path(directory).absolute() / str(int(step)))


def has_checkpoints(directory: str | Path) -> bool:
    """Whether ``directory`` holds at least one committed checkpoint (good or not)."""
    directory = Path(directory)
    if not directory.is_dir():
        return False
    with _manager(directory) as manager:
        return bool(manager.all_steps())


def restore_latest(
    directory: str | Path, abstract_state: Any, report: Callable[[str], None] = _warn
) -> tuple[Any, int]:
    """Restores the newest good checkpoint into the structure of ``abstract_state``.

    A newer checkpoint that fails its checksums or cannot be read is skipped; once an older
    one restores, the skipped ones are renamed ``<step>.corrupt`` and ``report`` is told
    (the default warns). If none restores, ValueError lists every step's problem and
    nothing is renamed.
    """
    directory = Path(directory)
    if not directory.is_dir():
        raise ValueError(f"no checkpoints in {directory}")
    problems: list[tuple[int, str]] = []
    unverified = False
    with _manager(directory) as manager:
        steps = sorted(manager.all_steps(), reverse=True)
        if not steps:
            raise ValueError(f"no complete checkpoint in {directory}")
        for step in steps:
            path = directory / str(step)
            try:
                unverified = not verify_checksums(path)
                target = _storable(abstract_state)
                stored = manager.restore(step, args=ocp.args.StandardRestore(target))
                break
            except ChecksumError as e:
                problems.append((step, str(e)))
            except Exception as e:  # orbax raises many types; name the directory instead
                problems.append((step, f"{path} is unreadable ({_short(e)})"))
        else:
            raise ValueError(
                f"no usable checkpoint in {directory}: "
                + "; ".join(f"step {s}: {problem}" for s, problem in problems)
            )
    for bad_step, problem in problems:
        aside = _set_aside(directory / str(bad_step))
        report(
            f"checkpoint at step {bad_step} is corrupt: {problem}; moved it to {aside}; "
            f"resuming from the previous good checkpoint, step {step}"
        )
    if unverified:
        report(
            f"checkpoint {directory / str(step)} has no recorded checksums (saved by an older "
            "version, or killed while recording them): restored without verifying it"
        )
    return _rebuild(stored, abstract_state), int(step)


def _set_aside(path: Path) -> Path:
    """Renames a corrupt step directory out of orbax's way (it ignores non-step names)."""
    aside = path.with_name(path.name + ".corrupt")
    n = 1
    while aside.exists():
        n += 1
        aside = path.with_name(f"{path.name}.corrupt-{n}")
    path.rename(aside)
    return aside


def save_tree(path: str | Path, tree: Any) -> Path:
    """Saves a pytree of arrays at ``path`` (replacing an older one only once complete)."""
    path = Path(path).absolute()
    tmp = path.with_name(path.name + ".partial")
    shutil.rmtree(tmp, ignore_errors=True)
    with ocp.StandardCheckpointer(multiprocessing_options=_this_process_only()) as ckptr:
        ckptr.save(tmp, tree)
        ckptr.wait_until_finished()
    record_checksums(tmp)  # inside the directory: renamed together, never out of step
    old = path.with_name(path.name + ".old")
    if path.exists():
        path.rename(old)
    tmp.rename(path)
    shutil.rmtree(old, ignore_errors=True)
    return path


def load_tree(path: str | Path, abstract: Any | None = None) -> Any:
    """Loads a pytree saved by ``save_tree`` (nested dicts of arrays if no ``abstract``).

    Verifies the recorded checksums first: corrupt parameters raise ValueError (one line,
    naming the file) instead of loading changed weights.
    """
    path = Path(path).absolute()
    if not path.is_dir():
        raise ValueError(f"no saved parameters at {path}")
    try:
        verified = verify_checksums(path)
    except ChecksumError as e:
        raise ValueError(f"parameters at {path} are corrupt: {e}") from None
    if not verified:
        _warn(f"parameters at {path} have no recorded checksums (saved by an older version)")
    try:
        with ocp.StandardCheckpointer(multiprocessing_options=_this_process_only()) as ckptr:
            tree = ckptr.restore(path, abstract) if abstract is not None else ckptr.restore(path)
    except Exception as e:
        raise ValueError(f"parameters at {path} are unreadable ({_short(e)})") from None
    return jax.tree_util.tree_map(_uncommitted, tree)
