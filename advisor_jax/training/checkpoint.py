"""Checkpoints with orbax: atomic, restorable, with clear errors on missing or corrupt data.

* ``save_step(dir, step, state)`` / ``restore_latest(dir, abstract_state)``: periodic full
  training state through an orbax ``CheckpointManager`` (each step is written to a
  temporary directory and committed by rename, so a crash never leaves a half-written
  checkpoint; the two newest are kept).
* ``save_tree(path, tree)`` / ``load_tree(path)``: one pytree (the final parameters).
"""

from __future__ import annotations

import shutil
from pathlib import Path
from typing import Any

import jax
import jax.numpy as jnp
import numpy as np
import orbax.checkpoint as ocp

_KEEP = 2


def _manager(directory: Path) -> ocp.CheckpointManager:
    return ocp.CheckpointManager(
        directory.absolute(),
        options=ocp.CheckpointManagerOptions(max_to_keep=_KEEP, create=True),
    )


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
    """Saves the full training state at environment step ``step`` (blocking)."""
    with _manager(Path(directory)) as manager:
        manager.save(int(step), args=ocp.args.StandardSave(_storable(state)), force=True)
        manager.wait_until_finished()


def restore_latest(directory: str | Path, abstract_state: Any) -> tuple[Any, int]:
    """Restores the newest checkpoint into the structure of ``abstract_state``."""
    directory = Path(directory)
    if not directory.is_dir():
        raise ValueError(f"no checkpoints in {directory}")
    with _manager(directory) as manager:
        step = manager.latest_step()
        if step is None:
            raise ValueError(f"no complete checkpoint in {directory}")
        try:
            target = _storable(abstract_state)
            stored = manager.restore(step, args=ocp.args.StandardRestore(target))
        except Exception as e:  # orbax raises many types; name the file instead
            raise ValueError(f"checkpoint {directory / str(step)} is unreadable: {e}") from e
    return _rebuild(stored, abstract_state), int(step)


def save_tree(path: str | Path, tree: Any) -> Path:
    """Saves a pytree of arrays at ``path`` (replacing an older one only once complete)."""
    path = Path(path).absolute()
    tmp = path.with_name(path.name + ".partial")
    shutil.rmtree(tmp, ignore_errors=True)
    with ocp.StandardCheckpointer() as ckptr:
        ckptr.save(tmp, tree)
        ckptr.wait_until_finished()
    old = path.with_name(path.name + ".old")
    if path.exists():
        path.rename(old)
    tmp.rename(path)
    shutil.rmtree(old, ignore_errors=True)
    return path


def load_tree(path: str | Path, abstract: Any | None = None) -> Any:
    """Loads a pytree saved by ``save_tree`` (nested dicts of arrays if no ``abstract``)."""
    path = Path(path).absolute()
    if not path.is_dir():
        raise ValueError(f"no saved parameters at {path}")
    try:
        with ocp.StandardCheckpointer() as ckptr:
            tree = ckptr.restore(path, abstract) if abstract is not None else ckptr.restore(path)
    except Exception as e:
        raise ValueError(f"parameters at {path} are unreadable: {e}") from e
    return jax.tree_util.tree_map(_uncommitted, tree)
