"""Replay a control-loop log through the policy and check it reproduces every decision.

The loop's ``Controller.cycle(now, scan, pose)`` is deterministic, and the log holds its
inputs bit-exactly (``cyclelog``). Replay rebuilds the controller from the log header
(goal, observation config, drive, loop limits) and the policy it names (checked by its
weights sha256), feeds the logged (t, scan, pose) of every cycle that ran, and compares the
watchdog state and reason, the observation, the action, the physical velocities and the
command with what was logged — exactly (float equality), since the same numpy code on the
same inputs must give the same bits. On another machine, a different BLAS may differ in the
last bit: ``tolerance`` allows for that.
"""

from __future__ import annotations

import dataclasses
import os

import numpy as np

from advisor_jax.runner.cyclelog import decode_pose, read_log
from advisor_jax.runner.drive import make_drive
from advisor_jax.runner.errors import ReplayError
from advisor_jax.runner.loop import Controller, CycleResult, LoopConfig
from advisor_jax.runner.observation import ObservationBuilder, ObservationConfig, Scan
from advisor_jax.runner.policy import Policy, load_policy

MAX_REPORTED = 20


@dataclasses.dataclass
class ReplayReport:
    cycles: int = 0
    replayed: int = 0
    driving: int = 0
    mismatched: int = 0
    max_action_diff: float = 0.0
    mismatches: list[str] = dataclasses.field(default_factory=list)

    @property
    def ok(self) -> bool:
        return self.mismatched == 0


def controller_from_header(header: dict, policy: Policy) -> Controller:
    """Rebuilds the logged run's controller around ``policy``."""
    try:
        obs_cfg = dict(header["observation"])
        if obs_cfg.get("bounds") is not None:
            obs_cfg["bounds"] = tuple(obs_cfg["bounds"])
        builder = ObservationBuilder(ObservationConfig(**obs_cfg), tuple(header["goal"]))
        return Controller(
            policy, builder, make_drive(header["drive"]), LoopConfig(**header["loop"])
        )
    except (KeyError, TypeError, ValueError) as e:
        raise ReplayError(f"log header cannot rebuild the controller: {e}") from None


def _same(logged, replayed, tolerance: float) -> tuple[bool, float]:
    if logged is None or replayed is None:
        return logged is None and replayed is None, 0.0
    a = np.asarray(logged, dtype=np.float64)
    b = np.asarray(replayed, dtype=np.float64)
    if a.shape != b.shape:
        return False, float("inf")
    d = np.where(np.isnan(a) & np.isnan(b), 0.0, np.abs(a - b))
    d = np.nan_to_num(d, nan=np.inf)  # NaN against a number never matches
    return bool((d <= tolerance).all()), float(d.max()) if d.size else 0.0


def _compare(rec: dict, result: CycleResult, tolerance: float) -> tuple[list[str], float]:
    problems = []
    if (rec["state"], rec["reason"]) != (result.state, result.reason):
        problems.append(f"state {rec['state']}/{rec['reason']} → {result.state}/{result.reason}")
    command = None if result.command is None else result.command.as_dict()
    logged_cmd = rec.get("command")
    if (command is None) != (logged_cmd is None) or (
        command is not None and command["kind"] != logged_cmd["kind"]
    ):
        problems.append(f"command {logged_cmd} → {command}")
        command = logged_cmd = None
    fields = {
        "obs": (rec.get("obs"), result.obs),
        "action": (rec.get("action"), result.action),
        "physical": (rec.get("physical"), result.physical),
        "command": (
            None if logged_cmd is None else [v for k, v in logged_cmd.items() if k != "kind"],
            None if command is None else [v for k, v in command.items() if k != "kind"],
        ),
    }
    action_diff = 0.0
    for name, (logged, replayed) in fields.items():
        same, diff = _same(logged, replayed, tolerance)
        if name == "action":
            action_diff = diff
        if not same:
            new = None if replayed is None else np.asarray(replayed).tolist()
            problems.append(f"{name} differs by {diff:.3g}: logged {logged}, replayed {new}")
    return problems, action_diff


def replay(
    log_path: str | os.PathLike,
    policy_dir: str | os.PathLike | None = None,
    *,
    tolerance: float = 0.0,
    verify_key: bytes | None = None,
) -> ReplayReport:
    """Re-runs every logged cycle; the report lists mismatches (empty when reproduced).

    Raises ReplayError for an unreadable or malformed log, a different policy, and a log in
    which no cycle ran the controller: replaying nothing must not read as success.
    """
    header, cycles = read_log(log_path)
    directory = policy_dir if policy_dir is not None else header.get("policy_dir", "")
    policy = load_policy(directory, verify_key=verify_key)
    if policy.weights_sha256 != header.get("weights_sha256"):
        raise ReplayError(
            f"policy {policy.directory} (weights {policy.weights_sha256[:12]}…) is not the one "
            f"the log was recorded with ({str(header.get('weights_sha256'))[:12]}…)"
        )
    controller = controller_from_header(header, policy)
    report = ReplayReport()
    try:
        _replay_cycles(controller, cycles, tolerance, report)
    except (KeyError, TypeError, ValueError) as e:  # a cycle record lacks or garbles a field
        what = f"missing field {e}" if isinstance(e, KeyError) else f"{type(e).__name__}: {e}"
        raise ReplayError(
            f"{log_path}: cycle record {report.cycles - 1} is malformed ({what})"
        ) from None
    if report.replayed == 0:  # nothing was compared: that is no proof of anything
        raise ReplayError(
            f"{log_path}: no cycles to replay: "
            + (
                "the log holds only its header (the loop never completed a cycle)"
                if report.cycles == 0
                else f"in all {report.cycles} cycles a source failed, so the controller never ran"
            )
        )
    return report


def _replay_cycles(controller: Controller, cycles, tolerance: float, report: ReplayReport) -> None:
    points, points_stamp = None, None
    for rec in cycles:
        report.cycles += 1
        scan_rec = rec.get("scan")
        if scan_rec is not None and "points" in scan_rec:
            points, points_stamp = scan_rec["points"], scan_rec["stamp"]
            if not isinstance(points, str):
                points = np.asarray(points, dtype=np.float64)
        if not rec.get("ran", False):
            continue  # a source failed: the controller did not run in this cycle
        scan = None
        if scan_rec is not None:
            if scan_rec["stamp"] != points_stamp:
                raise ReplayError(f"cycle {rec['i']}: scan {scan_rec['stamp']} has no points")
            scan = Scan(points, scan_rec["stamp"])
        result = controller.cycle(rec["t"], scan, decode_pose(rec.get("pose")))
        report.replayed += 1
        report.driving += result.state == "run"
        problems, action_diff = _compare(rec, result, tolerance)
        report.max_action_diff = max(report.max_action_diff, action_diff)
        if problems:
            report.mismatched += 1
            if len(report.mismatches) < MAX_REPORTED:
                report.mismatches.append(f"cycle {rec['i']}: " + "; ".join(problems))
