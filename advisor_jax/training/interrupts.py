"""Signals during training: noted where they land, acted on where the run is consistent.

A signal handler that raises (Python's default for Ctrl-C) stops the run wherever it lands:
after the step counter moved but before the chunk's log row was written (a resumed run then
lacks that row), inside orbax while it deletes an old checkpoint or before the new one has
its checksums, or inside the handler that saves the interrupt's checkpoint (a second Ctrl-C
0.15 s after the first printed a 48-line traceback and left run.json at "running"). So
while a run holds its directory, SIGINT, SIGTERM (kill, systemd, a batch scheduler) and
SIGHUP (a closed terminal, unless the run was started under ``nohup``) only *note* the
request::

    with stop_requests(console) as stop:
        ... a chunk, its log row, a periodic checkpoint ...
        stop.check()          # raises Interrupted(signum) here, between consistent states

The first signal prints one line saying that the run stops after the current step; later
ones change nothing (the checkpoint being saved is finished, never cut). ``kill -9`` remains
the way to stop at once: the run then resumes from its last checkpoint.
"""

from __future__ import annotations

import contextlib
import signal
import threading
from collections.abc import Callable, Iterator

HELD = (signal.SIGINT, signal.SIGTERM, signal.SIGHUP)


class Interrupted(KeyboardInterrupt):
    """A signal (``signum``) stopped the run; ``detail`` says where and how to continue."""

    def __init__(self, signum: int, detail: str = ""):
        super().__init__(f"signal {signum}")
        self.signum = signum
        self.detail = detail


class StopRequest:
    """The signal that asked the run to stop (None while none has)."""

    def __init__(self, announce: Callable[[str], None] | None = None):
        self.signum: int | None = None
        self._announce = announce

    def note(self, signum: int, frame=None) -> None:
        """Signal handler: remembers the first signal and says once what happens next."""
        if self.signum is not None:
            return
        self.signum = signum
        if self._announce is not None:
            name = signal.Signals(signum).name
            self._announce(f"{name}: stopping after the current step, with a checkpoint")

    @property
    def requested(self) -> bool:
        return self.signum is not None

    def check(self) -> None:
        """Raises ``Interrupted`` if a signal has asked the run to stop."""
        if self.signum is not None:
            raise Interrupted(self.signum)


@contextlib.contextmanager
def stop_requests(announce: Callable[[str], None] | None = None) -> Iterator[StopRequest]:
    """Holds SIGINT, SIGTERM and SIGHUP as stop requests for the ``with`` block.

    SIGHUP is taken only where its handler is the default one (a ``nohup`` run keeps
    ignoring it). Signal handlers can only be set from the main thread; elsewhere the
    signals keep their handlers and ``check`` never raises."""
    stop = StopRequest(announce)
    if threading.current_thread() is not threading.main_thread():
        yield stop
        return
    previous = {}
    for s in HELD:
        if s == signal.SIGHUP and signal.getsignal(s) is not signal.SIG_DFL:
            continue
        previous[s] = signal.signal(s, stop.note)
    try:
        yield stop
    finally:
        for s, handler in previous.items():
            signal.signal(s, handler)
