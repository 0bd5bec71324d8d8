"""Error types of the car runner.

Every problem the runner detects is a ``RunnerError``: the command-line tool turns it into one
clear line and a non-zero exit, and the control loop turns it into a stop command with a
logged reason. Subclasses say which part failed; ``ObservationError`` carries a short
machine-readable ``reason`` (``stale_scan``, ``pose_jump``, ...) that the watchdog logs.
"""

from __future__ import annotations


class RunnerError(Exception):
    """Base class of every error the runner raises on purpose."""


class PolicyError(RunnerError):
    """An exported policy is missing, corrupt, tampered with or inconsistent."""


class ObservationError(RunnerError):
    """A scan, pose or goal cannot be turned into a trustworthy observation.

    Attributes:
      reason: short code for logs and the watchdog, e.g. ``scan_nan`` or ``pose_jump``.
    """

    def __init__(self, reason: str, message: str):
        super().__init__(message)
        self.reason = reason


class HardwareError(RunnerError):
    """A sensor or motor adapter failed (missing driver package, bad datagram, I/O)."""


class ReplayError(RunnerError):
    """A log cannot be replayed (unreadable, wrong policy, missing header)."""
