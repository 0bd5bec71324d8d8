"""The car's own limits: the speed and yaw rate it never commands, whatever a policy says.

Every hash in an export detects damage, not a forger: whoever can write the policy
directory can edit ``v_max``, the heads' scales and the env together and recompute every
hash (the wheels then got 4.2-4.7 m/s instead of 0.65-1.14). So the limits come from the
car's side only, never from the policy directory:

    built-in spec (CAR_SPEC)  <  an operator's limits file (--limits FILE)  <  flags
    (--max-speed, --max-yaw-rate)

A limits file is a JSON object with any of ``max_speed`` (m/s), ``max_yaw_rate`` (rad/s)
and ``verify_key`` (a key file: every export must then carry a valid signature,
``signature.py``). ``check_policy`` refuses a policy whose commanded range goes beyond the
limits, before anything moves; ``LoopConfig`` carries them into the control loop, which
stops the car (reason ``beyond_car_limits``) instead of sending such a command, as a second
layer. The car prints its limits and where they came from when it starts.
"""

from __future__ import annotations

import dataclasses
import json
import math
import os
from typing import Any

from advisor_jax.contract import spec

CAR_SPEC = {"max_speed": spec.V_MAX, "max_yaw_rate": 3.0}
"""This runner's car: at most 1 m/s forward (``spec.V_MAX``, Table A1) and 3 rad/s of yaw
rate (the training arenas' ``omega_max``): the envelope the policies are trained in."""

LIMIT_KEYS = ("max_speed", "max_yaw_rate")
FILE_KEYS = (*LIMIT_KEYS, "verify_key")


@dataclasses.dataclass(frozen=True)
class CarLimits:
    """The car's speed and yaw-rate limits, and where they came from (for the start line)."""

    max_speed: float = CAR_SPEC["max_speed"]
    """m/s; no command asks for a faster forward speed."""
    max_yaw_rate: float = CAR_SPEC["max_yaw_rate"]
    """rad/s; no command asks for a faster turn."""
    source: str = "built-in car spec"

    def __post_init__(self):
        for name in LIMIT_KEYS:
            value = getattr(self, name)
            if isinstance(value, bool) or not isinstance(value, int | float):
                raise ValueError(f"car limit {name}={value!r} must be a number")
            if not (math.isfinite(value) and value > 0):
                raise ValueError(f"car limit {name}={value!r} must be a positive number")

    def describe(self) -> str:
        return (
            f"car limits: speed <= {self.max_speed:g} m/s, yaw rate <= {self.max_yaw_rate:g} "
            f"rad/s ({self.source})"
        )


def read_limits_file(path: str | os.PathLike) -> dict[str, Any]:
    """An operator's limits file: a JSON object with keys from ``FILE_KEYS`` only."""
    try:
        with open(path, encoding="utf-8") as f:
            data = json.load(f)
    except OSError as e:
        raise ValueError(f"--limits {path}: cannot read it ({e.strerror or e})") from None
    except (ValueError, RecursionError) as e:
        raise ValueError(f"--limits {path}: not a JSON object ({e})") from None
    if not isinstance(data, dict):
        raise ValueError(f"--limits {path}: not a JSON object ({type(data).__name__})")
    unknown = sorted(set(data) - set(FILE_KEYS))
    if unknown:
        raise ValueError(
            f"--limits {path}: unknown key(s) {', '.join(unknown)}; use {', '.join(FILE_KEYS)}"
        )
    return data


def car_limits(
    file_values: dict[str, Any] | None,
    max_speed: float | None,
    max_yaw_rate: float | None,
    file_name: str | None = None,
) -> CarLimits:
    """The limits in force: flags over the limits file over the built-in spec."""
    values, sources = dict(CAR_SPEC), []
    for key in LIMIT_KEYS:
        if file_values and key in file_values:
            values[key] = file_values[key]
            sources.append(f"{key} from {file_name}")
    for key, flag in (("max_speed", max_speed), ("max_yaw_rate", max_yaw_rate)):
        if flag is not None:
            values[key] = flag
            sources.append(f"{key} from --{key.replace('_', '-')}")
    return CarLimits(**values, source="; ".join(sources) or "built-in car spec")


def limits_from_options(
    limits_file: str | None,
    max_speed: float | None,
    max_yaw_rate: float | None,
    verify_key: str | None,
) -> tuple[CarLimits, bytes | None]:
    """(limits in force, signature key or None) from the car's options and limits file."""
    from advisor_jax.runner.signature import read_key

    from_file = read_limits_file(limits_file) if limits_file else None
    limits = car_limits(from_file, max_speed, max_yaw_rate, limits_file)
    key_path = verify_key or (from_file or {}).get("verify_key")
    if key_path is not None and not isinstance(key_path, str):
        raise ValueError(f"--limits {limits_file}: verify_key must be a file name")
    return limits, None if key_path is None else read_key(key_path)


def check_policy(json_path: str, v_max: float, omega_max: float, limits: CarLimits) -> None:
    """ValueError unless a policy's full-scale commands stay within the car's limits."""
    for what, value, limit, flag in (
        ("control.v_max", v_max, limits.max_speed, "--max-speed"),
        ("control.omega_max", omega_max, limits.max_yaw_rate, "--max-yaw-rate"),
    ):
        if not value <= limit:
            raise ValueError(
                f"{json_path}: {what} = {value:g} is beyond this car's limit of {limit:g} "
                f"({limits.source}); the car never commands more than its limits. If the car "
                f"is built for it, raise the limit with {flag} or --limits FILE"
            )


def within(v: float, w: float, max_speed: float, max_yaw_rate: float) -> bool:
    """Whether the physical command (v m/s, w rad/s) is inside the limits."""
    return 0.0 <= v <= max_speed and abs(w) <= max_yaw_rate
