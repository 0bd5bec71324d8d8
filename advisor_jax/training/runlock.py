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

``sigterm_as_interrupt()`` turns SIGTERM into ``Interrupted`` (a KeyboardInterrupt) while a
run holds its directory, so a kill, systemd or a batch scheduler saves a checkpoint as
Ctrl-C does instead of losing the run.
"""

from __future__ import annotations

import contextlib
import datetime
import fcntl
import json
import os
import signal
import socket
import threading
from collections.abc import Iterator
from pathlib import Path

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
    out_dir.mkdir(parents=True, exist_ok=True)
    path = out_dir / LOCK_FILE
    fd = os.open(path, os.O_RDWR | os.O_CREAT, 0o644)
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


class Interrupted(KeyboardInterrupt):
    """SIGTERM (``signum``) during training: handled like Ctrl-C's KeyboardInterrupt."""

    def __init__(self, signum: int):
        super().__init__(f"signal {signum}")
        self.signum = signum


@contextlib.contextmanager
def sigterm_as_interrupt():
    """Turns SIGTERM (kill, systemd, a batch scheduler) into ``Interrupted`` while training,
    so that it saves a checkpoint like Ctrl-C instead of losing the run. Signal handlers
    can only be set from the main thread; elsewhere SIGTERM keeps its handler."""
    if threading.current_thread() is not threading.main_thread():
        yield
        return

    def handler(signum, frame):
        raise Interrupted(signum)

    previous = signal.signal(signal.SIGTERM, handler)
    try:
        yield
    finally:
        signal.signal(signal.SIGTERM, previous)


@contextlib.contextmanager
def interrupts_deferred():
    """Holds SIGINT and SIGTERM back until the block ends, then raises what came.

    The jitted training chunk donates its input state: once called, the old state's
    buffers are gone. A Ctrl-C or SIGTERM that lands between the call taking them and
    returning the new state (during a compile, or while the dispatch waits for a full
    queue) would leave the run with no state to checkpoint ("Array has been deleted",
    seen on an H100 on 2026-11-23). Inside this block such a signal is only noted; at the
    end the handler that was in force (KeyboardInterrupt, ``Interrupted``) runs, when the
    new state is in hand. Elsewhere than the main thread signals keep their handlers."""
    if threading.current_thread() is not threading.main_thread():
        yield
        return
    caught: list[int] = []
    signals = (signal.SIGINT, signal.SIGTERM)
    previous = {s: signal.signal(s, lambda signum, frame: caught.append(signum)) for s in signals}
    try:
        yield
    finally:
        for s, handler in previous.items():
            signal.signal(s, handler)
    if caught:
        handler = previous[caught[0]]
        if callable(handler):
            handler(caught[0], None)
        elif handler == signal.SIG_DFL:  # default action (SIGINT's is KeyboardInterrupt)
            if caught[0] == signal.SIGINT:
                raise KeyboardInterrupt
            signal.raise_signal(caught[0])
