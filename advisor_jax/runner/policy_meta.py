"""policy.json of an export: its schema, its hashes, and the checks of every field the car
acts on against the values the actor was trained with.

``config_hash`` covers env and config; ``metadata_sha256`` (schema 2) covers the whole file;
``check_meta`` checks the schema, the layout against ``contract/spec.py`` and each section's
types and ranges; ``check_against_training`` requires control, heads and sensors to equal
``trained_values(env)``. Numpy and the standard library only (the car has no JAX).
"""

from __future__ import annotations

import hashlib
import json
import math
from typing import Any

from advisor_jax.contract import spec
from advisor_jax.runner.errors import PolicyError

SCHEMA_VERSION = 2
"""Schema 2 added ``metadata_sha256``. Schema 1 exports are still read: every field they hold
that changes what the car does is checked against the hash-covered ``env`` all the same."""
READABLE_SCHEMAS = (1, 2)
HEAD_ACTIVATIONS = ("sigmoid", "tanh")  # (V, ω), paper §5.3


def canonical_json(obj: Any) -> bytes:
    """Canonical JSON bytes (sorted keys, no spaces, ASCII, no NaN) used for hashing."""
    return json.dumps(
        obj, sort_keys=True, separators=(",", ":"), ensure_ascii=True, allow_nan=False
    ).encode("ascii")


def config_hash(config_meta: dict, env_meta: dict) -> str:
    """sha256 of the canonical JSON of ``{"config": config_meta, "env": env_meta}``."""
    return hashlib.sha256(canonical_json({"config": config_meta, "env": env_meta})).hexdigest()


def sha256_bytes(data: bytes) -> str:
    return hashlib.sha256(data).hexdigest()


def metadata_sha256(meta: dict) -> str:
    """sha256 of the canonical JSON of policy.json without its ``metadata_sha256`` field.

    ``config_hash`` covers only env and config; this covers every other field too (control,
    heads, sensors, observation, layers, the file hashes), so any edit of policy.json after
    export is refused. Like every hash here it detects accidents and careless edits, not a
    forger, who can recompute it: the cross-checks against the trained values still apply.
    """
    return sha256_bytes(canonical_json({k: v for k, v in meta.items() if k != "metadata_sha256"}))


def trained_values(env: dict) -> dict[str, Any]:
    """What the actor was trained with, read from the env metadata (covered by config_hash).

    The exporter derives policy.json's ``control``, heads and ``sensors`` sections from these
    (same defaults), and ``load_policy`` requires them to be equal: the car never drives with a
    speed, yaw rate, period, lidar offset or range cutoff other than the simulator's.
    """
    offset = env.get("lidar_range_offset")
    if not isinstance(offset, int | float):
        offset = env.get("robot_radius", 0.0)
    return {
        "v_max": env.get("v_max", spec.V_MAX),
        "omega_max": env.get("omega_max"),
        "dt": env.get("dt", spec.CONTROL_DT),
        "max_range": env.get("max_range", spec.MAX_RANGE),
        "lidar_range_offset": offset,
    }


def fail(path: str, problem: str) -> PolicyError:
    return PolicyError(f"{path}: {problem}")


def _positive(json_path: str, section: dict, key: str) -> None:
    value = section.get(key)
    if not isinstance(value, int | float) or not math.isfinite(value) or value <= 0:
        raise fail(json_path, f"{key}={value!r} must be a positive number")


def check_meta(json_path: str, meta: Any) -> None:
    if not isinstance(meta, dict):
        raise fail(json_path, "top level must be a JSON object")
    version = meta.get("schema_version")
    if type(version) is not int or version not in READABLE_SCHEMAS:
        raise fail(
            json_path,
            f"unsupported schema_version {version!r} (this runner reads "
            f"{', '.join(map(str, READABLE_SCHEMAS))})",
        )
    required = (
        "layers",
        "heads",
        "observation",
        "sensors",
        "control",
        "env",
        "config",
        "config_hash",
        "weights_sha256",
        "golden_sha256",
    ) + (("metadata_sha256",) if version >= 2 else ())
    missing = [k for k in required if k not in meta]
    if missing:
        raise fail(json_path, f"missing field(s) {', '.join(missing)}")
    if version >= 2:
        try:
            actual = metadata_sha256(meta)
        except (TypeError, ValueError) as e:
            raise fail(json_path, f"contents are not canonical JSON ({e})") from None
        if actual != meta["metadata_sha256"]:
            raise fail(
                json_path,
                f"metadata_sha256 {str(meta['metadata_sha256'])[:16]}… does not match its "
                f"contents ({actual[:16]}…): policy.json was edited after export",
            )
    for key in ("observation", "sensors", "control", "env", "config"):
        if not isinstance(meta[key], dict):
            raise fail(json_path, f"{key} must be a JSON object")
    if not isinstance(meta["heads"], list) or not all(isinstance(h, dict) for h in meta["heads"]):
        raise fail(json_path, "heads must be a list of objects")
    obs = meta["observation"]
    if obs.get("size") != spec.OBS_SIZE or tuple(obs.get("names", ())) != spec.OBS_NAMES:
        raise fail(
            json_path, f"observation layout {obs.get('names')} differs from this runner's spec.py"
        )
    sensors = meta["sensors"]
    zones = (sensors.get("n_zones"), sensors.get("zone_start_deg"), sensors.get("zone_width_deg"))
    if zones != (spec.N_ZONES, spec.ZONE_START_DEG, spec.ZONE_WIDTH_DEG):
        raise fail(json_path, f"zone definition {zones} differs from this runner's spec.py")
    heads = tuple(h.get("activation") for h in meta["heads"])
    if heads != HEAD_ACTIVATIONS:
        raise fail(json_path, f"head activations {heads} are not {HEAD_ACTIVATIONS}")
    for key in ("v_max", "omega_max", "dt"):
        _positive(json_path, meta["control"], key)
    _positive(json_path, obs, "max_range")
    offset = sensors.get("lidar_range_offset")
    if not isinstance(offset, int | float) or not math.isfinite(offset) or offset < 0:
        raise fail(json_path, f"lidar_range_offset={offset!r} must be a number >= 0")
    bounds = meta["env"].get("bounds")
    if bounds is not None and not (
        isinstance(bounds, list)
        and len(bounds) == 4
        and all(isinstance(b, int | float) and math.isfinite(b) for b in bounds)
        and bounds[0] < bounds[1]
        and bounds[2] < bounds[3]
    ):
        raise fail(json_path, f"env bounds {bounds!r} must be [xmin, xmax, ymin, ymax]")
    # The simulator's motion model the actor trained with (absent before there were two:
    # kinematic). The car drives itself either way; a model this runner does not know means
    # an export from a newer simulator, whose other assumptions it cannot check either.
    motion = meta["env"].get("motion", "kinematic")
    if not isinstance(motion, str) or motion.partition(":")[0] not in spec.MOTION_MODELS:
        raise fail(
            json_path,
            f"env.motion={motion!r}: trained with a motion model this runner does not know "
            f"(it knows {', '.join(spec.MOTION_MODELS)})",
        )
    try:
        expected = config_hash(meta["config"], meta["env"])
    except (TypeError, ValueError) as e:
        raise fail(json_path, f"env/config are not canonical JSON ({e})") from None
    if expected != meta["config_hash"]:
        raise fail(json_path, "config_hash does not match its env/config (metadata was edited)")
    check_against_training(json_path, meta)


def check_against_training(json_path: str, meta: dict) -> None:
    """Every field the car acts on must equal what the actor was trained with.

    policy.json repeats the training values in the sections the car reads (``control``,
    ``heads``, ``sensors``, ``observation``); ``config_hash`` covers only ``env``. A value
    that differs from its ``env`` original would make the car faster (v_max), turn harder
    (omega_max), run at another rate (dt) or see obstacles nearer or farther (lidar offset,
    range cutoff) than in training, so it is refused, naming the field and both values.
    """
    trained = trained_values(meta["env"])
    for name, value in trained.items():
        if isinstance(value, bool) or not isinstance(value, int | float):
            raise fail(json_path, f"env.{name}={value!r} (the trained value) is not a number")
    control, sensors, obs = meta["control"], meta["sensors"], meta["observation"]
    heads = {h.get("name"): h for h in meta["heads"]}
    fields = [
        ("control.v_max", control.get("v_max"), "v_max"),
        ("control.omega_max", control.get("omega_max"), "omega_max"),
        ("control.dt", control.get("dt"), "dt"),
        ("heads[V].scale", heads.get("V", {}).get("scale"), "v_max"),
        ("heads[omega].scale", heads.get("omega", {}).get("scale"), "omega_max"),
        ("sensors.lidar_range_offset", sensors.get("lidar_range_offset"), "lidar_range_offset"),
        ("sensors.max_range", sensors.get("max_range"), "max_range"),
        ("observation.max_range", obs.get("max_range"), "max_range"),
    ]
    for where, value, name in fields:
        if value != trained[name]:
            beyond = (
                " (beyond the trained limit)"
                if name in ("v_max", "omega_max")
                and isinstance(value, int | float)
                and value > trained[name]
                else ""
            )
            raise fail(
                json_path,
                f"{where}={value!r} differs from {name}={trained[name]!r} the actor was "
                f"trained with (env.{name}){beyond}",
            )
    boxes = (
        ("control.action_names", control.get("action_names"), list(spec.ACTION_NAMES)),
        ("control.action_low", control.get("action_low"), list(spec.ACTION_LOW)),
        ("control.action_high", control.get("action_high"), list(spec.ACTION_HIGH)),
        (
            "heads[V].range",
            heads.get("V", {}).get("range"),
            [spec.ACTION_LOW[0], spec.ACTION_HIGH[0]],
        ),
        (
            "heads[omega].range",
            heads.get("omega", {}).get("range"),
            [spec.ACTION_LOW[1], spec.ACTION_HIGH[1]],
        ),
        (
            "sensors.sonar_directions_deg",
            sensors.get("sonar_directions_deg"),
            list(spec.SONAR_DIRECTIONS_DEG),
        ),
    )
    for where, value, expected in boxes:
        if value != expected:
            raise fail(json_path, f"{where}={value!r} differs from this runner's {expected!r}")
