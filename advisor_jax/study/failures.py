"""Which devices a sweep's pieces failed on: where a retry goes, and when a device is retired.

A piece that fails is started once more (``sweep.run_jobs``), on a device it has not failed
on: if every free device is one it failed on and another device that it has not failed on is
still in use (``Failures.may_start``), it waits for that one rather than run again where it
failed. A device on which ``RETIRE_AFTER`` pieces failed in a row (another process holds
its memory, a broken GPU) takes no more pieces in this call.
"""

from __future__ import annotations

from pathlib import Path

from rich.console import Console

from advisor_jax.study.plan import Device

RETIRE_AFTER = 2  # pieces failed in a row on one device: it takes no more in this call


class Failures:
    """The devices each piece failed on; ``retired``: devices on which ``RETIRE_AFTER``
    pieces failed in a row (another process holds the memory, a broken GPU)."""

    def __init__(self, console: Console):
        self.console = console
        self.tries: dict[tuple[int, int], list] = {}  # (job, piece) -> devices it failed on
        self.in_a_row: dict = {}  # device index -> failures since its last success
        self.retired: set = set()

    def may_start(self, key: tuple[int, int], free: list[Device], live: set) -> bool:
        """Whether the piece ``key`` may start now on one of the ``free`` devices: on one it
        has not failed on; where it failed on every free one, only if no other device of
        ``live`` (the indices not retired) is left that it has not failed on: otherwise it
        waits for that device to come free."""
        tried = self.tries.get(key, [])
        return any(d.index not in tried for d in free) or all(i in tried for i in live)

    def elsewhere(self, free: list[Device], key: tuple[int, int]) -> Device:
        """The first free device the piece has not failed on (else the first free one)."""
        return next((d for d in free if d.index not in self.tries.get(key, [])), free[0])

    def succeeded(self, device: Device) -> None:
        self.in_a_row[device.index] = 0

    def failed(self, w, out: Path) -> bool:
        """Records a failed worker (``sweep``'s: its device, job, piece and process) and
        says so; True: start its piece once more."""
        where, key = w.device.index, (w.job, w.piece.index)
        self.tries.setdefault(key, []).append(where)
        self.in_a_row[where] = self.in_a_row.get(where, 0) + 1
        again = len(self.tries[key]) == 1
        log, more = out / "logs" / f"{w.piece.name}.log", "; it will be started once more"
        self.console.print(
            f"[red]piece {w.piece.index} ({w.piece.name}) of {out} failed on "
            f"{device_name(w.device)} (exit {w.process.returncode}; {log}){more * again}[/]"
        )
        if self.in_a_row[where] >= RETIRE_AFTER and where not in self.retired:
            self.retired.add(where)
            self.console.print(
                f"[red]{device_name(w.device)}: {self.in_a_row[where]} pieces in a row failed "
                "on it; it takes no more pieces in this call[/]"
            )
        return again


def device_name(device: Device) -> str:
    return "the CPU" if device.index is None else f"GPU {device.index}"
