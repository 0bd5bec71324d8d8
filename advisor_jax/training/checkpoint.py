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
a warning.

Identity. Each ``sha256.json`` also records the run it belongs to (``run``: the
``run_state.run_identity`` of its config and seeds). Given that identity, ``save_step``,
``restore_latest`` and ``load_tree`` require the manifest and refuse a directory of another
run (``ForeignRunError``) instead of skipping a save, resuming from or exporting another
run's state; the checkpoint of a killed save that lacks its manifest is then set aside like
a corrupt one, and a deleted ``params/sha256.json`` no longer turns the check off.

Errors are one line: orbax/TensorStore messages are cut to their first line, a failed
write (a full disk) names the directory and the reason, and orbax's background threads'
logs and late tracebacks about it are kept off the terminal.
"""

from __future__ import annotations

import contextlib
import logging
import os
import re
import shutil
import sys
import time
import warnings
from collections.abc import Callable
from pathlib import Path
from typing import Any

import jax
import jax.numpy as jnp
import numpy as np
import orbax.checkpoint as ocp

from advisor_jax.training.manifest import (  # noqa: F401 (callers reach them from here)
    CHECKSUMS,
    ChecksumError,
    ForeignRunError,
    check_run,
    manifest_sha256,
    read_manifest,
    record_checksums,
    verify_checksums,
)

_KEEP = 2
_MAX_MESSAGE = 200


def _short(e: BaseException) -> str:
    """First line of an exception's message, cut to a readable length (TensorStore's run to
    kilobytes of JSON)."""
    text = str(e).strip().splitlines()[0] if str(e).strip() else ""
    text = text if len(text) <= _MAX_MESSAGE else text[:_MAX_MESSAGE] + "…"
    return f"{type(e).__name__}: {text}" if text else type(e).__name__


def _warn(message: str) -> None:
    warnings.warn(message, stacklevel=3)


def _write_failure(what: Path, e: BaseException) -> OSError:
    """One line for a failed orbax save: 'cannot save DIR: No space left on device'."""
    code = re.search(r"os_error_code='?(\d+)", str(e))
    reason = os.strerror(int(code.group(1))) if code else _short(e)
    return OSError(f"cannot save {what}: {reason}")


@contextlib.contextmanager
def _quiet_orbax():
    """Keeps orbax's own error logs (absl, from its background threads) off the terminal
    while it saves: a failure reaches the caller as one exception, worded here. When a
    write fails, its threads also report on event loops already closed, during the save
    and after it; those echoes are dropped (``_drop_closed_loop_echoes``)."""
    _drop_closed_loop_echoes()
    logger = logging.getLogger("absl")
    level = logger.level
    logger.setLevel(logging.CRITICAL)
    try:
        yield
    finally:
        logger.setLevel(level)


def _drop_closed_loop_echoes() -> None:
    """Installs (once) an unraisable-exception hook that drops orbax's "Event loop is closed"
    RuntimeErrors, raised in TensorStore callbacks when a save fails (61 tracebacks on a
    full disk), and passes every other unraisable exception on."""
    previous = sys.unraisablehook
    if getattr(previous, "_drops_closed_loop_echoes", False):
        return

    def hook(args):
        if isinstance(args.exc_value, RuntimeError) and "Event loop is closed" in str(
            args.exc_value
        ):
            return
        previous(args)

    hook._drops_closed_loop_echoes = True
    sys.unraisablehook = hook


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
    that, so a resumed run would otherwise recompile its chunk function. And in the
    abstract leaf's dtype: a checkpoint written before a state's storage changed (a bf16
    learner's Adam moments on GPUs, ``networks.Layout.bf16_first_moment`` and
    ``bf16_second_moment``: m was fp32 before 2026-11-27, v before 2026-11-28) resumes
    rounded to the program's dtypes.
    """
    leaves, treedef = jax.tree_util.tree_flatten(abstract)
    full = [
        _uncommitted(stored[f"{i:04d}"], leaf.dtype)
        if leaf.size
        else jnp.zeros(leaf.shape, leaf.dtype)
        for i, leaf in enumerate(leaves)
    ]
    return jax.tree_util.tree_unflatten(treedef, full)


def _uncommitted(x, dtype=None) -> jax.Array:
    """``x`` as an uncommitted JAX array, in ``dtype`` (None: its own)."""
    return jnp.asarray(np.asarray(x, dtype=dtype))


def save_step(directory: str | Path, step: int, state: Any, run: dict | None = None) -> None:
    """Saves the full training state at environment step ``step`` (blocking), then records
    its checksums (and ``run``, the run's identity).

    If a checkpoint of ``step`` exists already, nothing is written: the run is at the step it
    just saved or resumed from, so the state is that checkpoint's (an interrupt right after a
    periodic save, or before the first chunk after a resume, used to fail on orbax's
    "Checkpoint for step N already exists"). With ``run``, that checkpoint must be this
    run's (``ForeignRunError`` otherwise: the step of another run is never kept as ours).
    """
    directory = Path(directory).absolute()
    failure = None
    with _manager(directory) as manager:
        if int(step) in manager.all_steps():
            if run is not None:
                existing = directory / str(int(step))
                check_run(existing, run, read_manifest(existing))
            return
        try:
            with _quiet_orbax():
                manager.save(int(step), args=ocp.args.StandardSave(_storable(state)), force=True)
                manager.wait_until_finished()
        except Exception as e:
            failure = e
            with contextlib.suppress(Exception):
                manager.wait_until_finished()  # let no writer thread outlive the failure
    if failure is not None:
        # Only now, with the manager closed and its writer threads joined, can no thread
        # write into the half-written step again after it is removed.
        _remove_partial_step(directory, int(step))
        raise _write_failure(directory / str(int(step)), failure) from None
    record_checksums(directory / str(int(step)), run)


def _remove_partial_step(directory: Path, step: int, tries: int = 50) -> None:
    """Removes a failed save's temporary folder. A removal can race with a last file that
    orbax's writer was still closing (the folder is then not empty and stays), so it is
    repeated until the folder is gone twice in a row, 0.1 s apart."""
    gone = 0
    for _ in range(tries):
        partials = list(directory.glob(f"{step}.orbax-checkpoint-tmp*"))
        for partial in partials:
            shutil.rmtree(partial, ignore_errors=True)
        gone = gone + 1 if not partials else 0
        if gone == 2:
            return
        time.sleep(0.1)


def has_checkpoints(directory: str | Path) -> bool:
    """Whether ``directory`` holds at least one committed checkpoint (good or not)."""
    directory = Path(directory)
    if not directory.is_dir():
        return False
    with _manager(directory) as manager:
        return bool(manager.all_steps())


def restore_latest(
    directory: str | Path,
    abstract_state: Any,
    report: Callable[[str], None] = _warn,
    run: dict | None = None,
) -> tuple[Any, int]:
    """Restores the newest good checkpoint into the structure of ``abstract_state``.

    A newer checkpoint that fails its checksums or cannot be read is skipped; once an older
    one restores, the skipped ones are renamed ``<step>.corrupt`` and ``report`` is told
    (the default warns). If none restores, ValueError lists every step's problem and
    nothing is renamed. With ``run`` (the run's identity) every checkpoint needs its
    manifest (one without is skipped like a corrupt one), and a checkpoint of another run
    raises ``ForeignRunError`` at once: it is not damage to step over.
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
                unverified = not verify_checksums(path, run)
                target = _storable(abstract_state)
                stored = manager.restore(step, args=ocp.args.StandardRestore(target))
                break
            except ForeignRunError:
                raise
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


def save_tree(path: str | Path, tree: Any, run: dict | None = None) -> Path:
    """Saves a pytree of arrays at ``path`` (replacing an older one only once complete),
    with its checksums and, if given, its ``run``'s identity."""
    path = Path(path).absolute()
    tmp = path.with_name(path.name + ".partial")
    old = path.with_name(path.name + ".old")
    for leftover in (tmp, old):  # of a killed save; a link is removed, never followed
        _remove(leftover)
    try:
        with _quiet_orbax():
            with ocp.StandardCheckpointer(multiprocessing_options=_this_process_only()) as ckptr:
                ckptr.save(tmp, tree)
                ckptr.wait_until_finished()
    except Exception as e:
        _remove(tmp)
        raise _write_failure(path, e) from None
    record_checksums(tmp, run)  # inside the directory: renamed together, never out of step
    if path.is_symlink() or path.exists():
        path.rename(old)
    tmp.rename(path)
    _remove(old)
    return path


def _remove(path: Path) -> None:
    """Removes a file, a link (not its target) or a directory tree, if there is one."""
    if path.is_symlink() or path.is_file():
        path.unlink()
    elif path.exists():
        shutil.rmtree(path, ignore_errors=True)


def load_tree(
    path: str | Path,
    abstract: Any | None = None,
    run: dict | None = None,
    manifest: str | None = None,
) -> Any:
    """Loads a pytree saved by ``save_tree`` (nested dicts of arrays if no ``abstract``).

    Verifies the recorded checksums first: corrupt parameters raise ValueError (one line,
    naming the file) instead of loading changed weights. With ``run`` the checksums are
    required and must be that run's (``ForeignRunError``); with ``manifest`` (the sha256
    run.json recorded for them) ``sha256.json`` itself must be the one saved with the run.
    """
    path = Path(path).absolute()
    if not path.is_dir():
        raise ValueError(f"no saved parameters at {path}")
    try:
        verified = verify_checksums(path, run)
        if manifest is not None and manifest_sha256(path) != manifest:
            raise ChecksumError(
                f"{path / CHECKSUMS} is not the one saved with this run's run.json (the "
                "parameters were replaced)"
            )
    except ForeignRunError as e:
        raise ForeignRunError(f"parameters at {path} are not this run's: {e}") from None
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
