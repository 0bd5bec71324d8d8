"""Exclusive use of a run directory: one process trains into one ``--out`` at a time.

Two runs writing into the same directory mix their checkpoints and logs (one run's results
silently replace the other's, or orbax stops one with "Checkpoint for step N already
exists"), and a second ``--resume`` of a running run does the same. So ``exclusive(out_dir)``
takes ``fcntl.flock(LOCK_EX | LOCK_NB)`` on ``out_dir/.lock`` for the whole run and writes
the holder's pid, host and start time into that file; a second taker gets ``RunDirectoryBusy``
(a ValueError) naming them.

The kernel drops a flock when its process ends, however it ends (kill -9 included), so a
lock file left behind never blocks a later run and needs no cleaning; it is never deleted
(a process that deleted it could let a third one lock a new file while the second still
holds the old one). flock is reliable on local file systems; on NFS it depends on the
server, which is why the message names the host.

The lock file is opened without following a link (``O_NOFOLLOW``) and must be a regular
file with one name: a ``.lock`` that is a symbolic or hard link to a file outside ``--out``
would otherwise be truncated and overwritten with the holder record. Signals while a run
holds its directory: ``interrupts``.
"""

from __future__ import annotations

import contextlib
import datetime
import fcntl
import json
import os
import socket
from collections.abc import Iterator
from pathlib import Path

from advisor_jax.fileio import open_no_follow
from advisor_jax.training.interrupts import Interrupted  # noqa: F401 (its old home)

LOCK_FILE = ".lock"


class RunDirectoryBusy(ValueError):
    """Another process holds the run directory."""


def _holder(fd: int) -> str:
    """'pid N on host H (since T)' from the lock file, or a fallback if unreadable."""
    try:
        info = json.loads(os.pread(fd, 4096, 0).decode("utf-8"))
        return f"pid {info['pid']} on host {info['host']} (since {info['started']})"
    except (OSError, ValueError, KeyError, TypeError):
        return "another process (it has not written its pid yet)"


@contextlib.contextmanager
def exclusive(out_dir: str | os.PathLike) -> Iterator[dict]:
    """Holds ``out_dir`` (created if missing) for the duration of the ``with`` block.

    Yields the holder record written into the lock file: ``{"pid", "host", "started"}``.
    Raises RunDirectoryBusy, naming the holder, if another process (or another ``exclusive``
    in this one) holds it.
    """
    out_dir = Path(out_dir)
    try:
        out_dir.mkdir(parents=True, exist_ok=True)
    except FileExistsError:
        raise OSError(f"--out {out_dir} exists and is not a directory") from None
    path = out_dir / LOCK_FILE
    fd = open_no_follow(path, os.O_RDWR | os.O_CREAT)
    try:
        try:
            fcntl.flock(fd, fcntl.LOCK_EX | fcntl.LOCK_NB)
        except BlockingIOError:
            raise RunDirectoryBusy(
                f"{out_dir} is in use by another run: {_holder(fd)}; wait for it to end, "
                "stop it, or choose another --out"
            ) from None
        info = {
            "pid": os.getpid(),
            "host": socket.gethostname(),
            "started": datetime.datetime.now(datetime.UTC).isoformat(timespec="seconds"),
        }
        os.ftruncate(fd, 0)
        os.pwrite(fd, (json.dumps(info) + "\n").encode("utf-8"), 0)
        yield info
    finally:
        os.close(fd)  # releases the lock
