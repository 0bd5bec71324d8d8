"""Export a trained actor for the numpy-only car runner (paper §5.3), and its inverse.

docs/architecture.md, "Deployment".

``export_policy`` writes an export directory that ``advisor_jax.runner.policy.load_policy``
reads and verifies on the car::

    policy.npz    float32 "hidden_i/kernel" [in, out] (flax layout), "hidden_i/bias", "head/..."
    golden.npz    obs [N >= 256, 20] and actions [N, 2] from the JIT-compiled JAX actor
    policy.onnx   (optional) the same MLP at opset 13 (``runner/onnx_model.py``)
    policy.json   metadata (schema 2): layers, heads, observation/sensor layout, control
                  scaling, env and config, config_hash, sha256 of every file and of
                  policy.json's own contents (metadata_sha256)

Outline::

    arrays   = float32 copy of the actor params, checked against actor_hidden
    obs      = caller's rollout observations ++ edge cases ++ seeded random fill to 256 rows
    actions  = jax.jit(make_actor(hidden).apply)(arrays, obs)   on CPU, "highest" matmul precision
               (a GPU's default TF32 matmuls would miss the runner's 1e-5 check)
    verify   numpy MLP == actions (1e-5); ONNX via onnxruntime == actions (1e-5) if asked
    write    each file atomically (temp file in out_dir, fsync, os.replace); policy.json last
    reload   with the runner's load_policy, which repeats every check from the files

Non-finite floats in env/config metadata (e.g. N_T = inf) are stored as the strings "inf",
"-inf", "nan" so that policy.json stays strict JSON.
"""

from __future__ import annotations

import dataclasses
import datetime
import io
import json
import math
import os
from collections.abc import Mapping, Sequence
from typing import Any

import jax
import jax.numpy as jnp
import numpy as np

from advisor_jax import __version__
from advisor_jax.agent.networks import make_actor
from advisor_jax.contract import spec
from advisor_jax.deploy.golden import ExportError, golden_observations
from advisor_jax.fileio import atomic_write_bytes
from advisor_jax.runner import policy as rp
from advisor_jax.runner import policy_meta as pm
from advisor_jax.runner.errors import RunnerError
from advisor_jax.runner.onnx_model import build_onnx

ONNX_OPSET = 13  # the Jetson's onnxruntime is old


def export_policy(
    actor_params: Mapping,
    out_dir: str | os.PathLike,
    *,
    actor_hidden: Sequence[int],
    env_meta: dict,
    config_meta: dict,
    golden_obs: np.ndarray,
    onnx: bool = False,
) -> dict:
    """Writes policy.npz, golden.npz, [policy.onnx,] policy.json into ``out_dir``.

    Args:
      actor_params: flax params of ``make_actor(actor_hidden)`` (with or without the "params" key).
      out_dir: directory to create or overwrite.
      actor_hidden: hidden widths, e.g. (600, 300).
      env_meta: ``NavEnv.metadata()``; needs ``omega_max`` and ``bounds``.
      config_meta: preset, agent name, hyperparameters, ... (anything JSON-able).
      golden_obs: [N, 20] rollout observations; edge cases and a random fill are appended.
      onnx: also write policy.onnx (needs the ``onnx`` extra).

    Returns:
      The policy.json dict.

    Long: one straight sequence (check, verify against numpy, describe, write, reload as
    the car does), most of it the literal policy.json; its order is the point.
    """
    hidden = tuple(int(w) for w in actor_hidden)
    layers = _actor_layers(actor_params, hidden)
    env = _jsonable(env_meta, "env_meta")
    config = _jsonable(config_meta, "config_meta")
    control, sensors, observation = _describe(env)
    obs = golden_observations(golden_obs, observation["max_range"])
    actions = _jax_actions(layers, hidden, obs)
    golden = {"obs": obs, "actions": actions}
    try:
        rp.verify_golden(rp.GOLDEN_NPZ, layers, golden)
    except rp.PolicyError as e:
        raise ExportError(f"numpy reference disagrees with the JAX actor: {e}") from None
    onnx_bytes = None
    if onnx:
        try:
            onnx_bytes = build_onnx(layers, obs, actions, opset=ONNX_OPSET)
        except RunnerError as e:
            raise ExportError(str(e)) from None

    out_dir = os.fspath(out_dir)
    os.makedirs(out_dir, exist_ok=True)
    weights = _npz_bytes(
        {f"{layer.name}/{p}": getattr(layer, p) for layer in layers for p in ("kernel", "bias")}
    )
    golden_bytes = _npz_bytes(golden)
    meta = {
        "schema_version": pm.SCHEMA_VERSION,
        "layers": [
            {
                "name": x.name,
                "in": int(x.kernel.shape[0]),
                "out": int(x.kernel.shape[1]),
                "activation": "heads" if x.name == "head" else "relu",
            }
            for x in layers
        ],
        "heads": [
            {
                "name": "V",
                "activation": "sigmoid",
                "range": [0.0, 1.0],
                "scale": control["v_max"],
                "unit": "m/s",
            },
            {
                "name": "omega",
                "activation": "tanh",
                "range": [-1.0, 1.0],
                "scale": control["omega_max"],
                "unit": "rad/s",
            },
        ],
        "observation": observation,
        "sensors": sensors,
        "control": control,
        "env": env,
        "config": config,
        "config_hash": pm.config_hash(config, env),
        "weights_sha256": pm.sha256_bytes(weights),
        "golden_sha256": pm.sha256_bytes(golden_bytes),
        "golden_size": len(obs),
        "onnx_sha256": None if onnx_bytes is None else pm.sha256_bytes(onnx_bytes),
        "created": datetime.datetime.now(datetime.UTC).isoformat(timespec="seconds"),
        "advisor_jax_version": __version__,
    }
    meta["metadata_sha256"] = pm.metadata_sha256(meta)  # last: covers every field above
    atomic_write_bytes(os.path.join(out_dir, rp.POLICY_NPZ), weights)
    atomic_write_bytes(os.path.join(out_dir, rp.GOLDEN_NPZ), golden_bytes)
    onnx_path = os.path.join(out_dir, rp.POLICY_ONNX)
    if onnx_bytes is not None:
        atomic_write_bytes(onnx_path, onnx_bytes)
    elif os.path.exists(onnx_path):
        os.remove(onnx_path)  # a stale model from an earlier export would not match
    text = json.dumps(meta, indent=1, allow_nan=False)  # strict JSON, indented for humans
    atomic_write_bytes(os.path.join(out_dir, rp.POLICY_JSON), (text + "\n").encode("utf-8"))
    rp.load_policy(out_dir)  # end-to-end: exactly what the car will do
    return meta


def _actor_layers(actor_params: Mapping, hidden: tuple[int, ...]) -> tuple[rp.Layer, ...]:
    if not hidden or any(w <= 0 for w in hidden):
        raise ExportError(f"actor_hidden must be positive widths, got {hidden}")
    params = actor_params.get("params", actor_params) if isinstance(actor_params, Mapping) else None
    if not isinstance(params, Mapping):
        raise ExportError(f"actor_params must be a flax params dict, got {type(actor_params)}")
    names = [f"hidden_{i}" for i in range(len(hidden))] + ["head"]
    widths = (spec.OBS_SIZE, *hidden, spec.ACTION_SIZE)
    if sorted(params) != sorted(names):
        raise ExportError(f"actor_params has layers {sorted(params)}, expected {names}")
    layers = []
    for i, name in enumerate(names):
        kernel = np.asarray(jax.device_get(params[name]["kernel"]), dtype=np.float32)
        bias = np.asarray(jax.device_get(params[name]["bias"]), dtype=np.float32)
        if kernel.shape != (widths[i], widths[i + 1]) or bias.shape != (widths[i + 1],):
            raise ExportError(
                f"actor_params[{name!r}] has kernel {list(kernel.shape)} / bias "
                f"{list(bias.shape)}, expected [{widths[i]}, {widths[i + 1]}] for "
                f"actor_hidden={hidden}"
            )
        if not (np.isfinite(kernel).all() and np.isfinite(bias).all()):
            raise ExportError(f"actor_params[{name!r}] contains NaN or inf")
        layers.append(rp.Layer(name, kernel, bias))
    return tuple(layers)


def _jax_actions(
    layers: Sequence[rp.Layer], hidden: tuple[int, ...], obs: np.ndarray
) -> np.ndarray:
    params = {
        "params": {layer.name: {"kernel": layer.kernel, "bias": layer.bias} for layer in layers}
    }
    try:
        device = jax.devices("cpu")[0]
    except RuntimeError:  # JAX_PLATFORMS without cpu: full precision still applies
        device = jax.devices()[0]
    apply = jax.jit(make_actor(hidden).apply)
    with jax.default_matmul_precision("highest"):
        params, x = jax.device_put((params, jnp.asarray(obs)), device)
        actions = np.asarray(jax.device_get(apply(params, x)), dtype=np.float32)
    if not np.isfinite(actions).all():
        raise ExportError("the JAX actor produced NaN/inf actions on the golden set")
    return actions


def _describe(env: dict) -> tuple[dict, dict, dict]:
    """(control, sensors, observation) sections of policy.json from the env metadata."""
    for key in ("omega_max", "bounds"):
        if key not in env:
            raise ExportError(f"env_meta lacks {key!r} (pass NavEnv.metadata())")
    bounds = env["bounds"]
    if (
        not isinstance(bounds, list)
        or len(bounds) != 4
        or not all(isinstance(b, int | float) for b in bounds)
        or not (bounds[0] < bounds[1] and bounds[2] < bounds[3])
    ):
        raise ExportError(f"env_meta bounds={bounds!r} must be [xmin, xmax, ymin, ymax]")
    trained = pm.trained_values(env)  # the runner checks every copy below against these
    control = {
        "v_max": trained["v_max"],
        "omega_max": trained["omega_max"],
        "dt": trained["dt"],
        "action_names": list(spec.ACTION_NAMES),
        "action_low": list(spec.ACTION_LOW),
        "action_high": list(spec.ACTION_HIGH),
    }
    max_range = trained["max_range"]
    for key, value in (
        ("v_max", control["v_max"]),
        ("omega_max", control["omega_max"]),
        ("dt", control["dt"]),
        ("max_range", max_range),
    ):
        if not isinstance(value, int | float) or not math.isfinite(value) or value <= 0:
            raise ExportError(f"env_meta {key}={value!r} must be a positive number")
    # The car's lidar sits at the centre; zones read free distance beyond the body edge.
    offset = trained["lidar_range_offset"]
    if not isinstance(offset, int | float) or not math.isfinite(offset) or offset < 0:
        raise ExportError(f"env_meta lidar_range_offset={offset!r} must be a number >= 0")
    sensors = {
        "n_zones": spec.N_ZONES,
        "zone_start_deg": spec.ZONE_START_DEG,
        "zone_width_deg": spec.ZONE_WIDTH_DEG,
        "zone_rule": "zone k holds robot-frame angles a (deg, CCW, 0 = forward) with "
        "90 - 22.5 (k + 1) < a <= 90 - 22.5 k (mod 360)",
        "order": "P3DX sonar ring: zone 0 points left (+90 deg), clockwise over the front to "
        "the right (zone 7, -90 deg), then over the rear back to the left (zone 15)",
        "reduction": "minimum free distance (range - lidar_range_offset) per zone, clipped to "
        "[0, max_range]; an empty zone reads max_range",
        "lidar_range_offset": float(offset),
        "max_range": float(max_range),
        "sonar_directions_deg": list(spec.SONAR_DIRECTIONS_DEG),
    }
    observation = {
        "size": spec.OBS_SIZE,
        "names": list(spec.OBS_NAMES),
        "units": list(spec.OBS_UNITS),
        "layout": {"proximity": [0, 16], "delta": 16, "d": 17, "velocity": [18, 20]},
        "frames": {
            "world": "arena frame: x right, y up, origin at the arena centre, metres",
            "heading": "theta: robot forward axis from world +x, counter-clockwise positive",
            "robot": "robot-frame angles: 0 = straight ahead, counter-clockwise positive",
            "delta": "heading to goal direction, CCW positive, wrapped to [-pi, pi)",
            "velocity": "v_x, v_y in the WORLD frame: displacement over the last control "
            "period / dt, 0 at the first step",
        },
        "normalisation": "none (raw values)",
        "max_range": float(max_range),
    }
    return control, sensors, observation


def _jsonable(obj: Any, where: str) -> Any:
    """Plain JSON types; tuples → lists, numpy/jax scalars and arrays → Python values."""
    if dataclasses.is_dataclass(obj) and not isinstance(obj, type):
        obj = {f.name: getattr(obj, f.name) for f in dataclasses.fields(obj)}
    if isinstance(obj, Mapping):
        out = {}
        for k, v in obj.items():
            if not isinstance(k, str):
                raise ExportError(f"{where}: key {k!r} is not a string")
            out[k] = _jsonable(v, f"{where}.{k}")
        return out
    if isinstance(obj, list | tuple):
        return [_jsonable(v, f"{where}[{i}]") for i, v in enumerate(obj)]
    if obj is None or isinstance(obj, bool | str):
        return obj
    if isinstance(obj, int | float | np.generic) or hasattr(obj, "__array__"):
        arr = np.asarray(obj)
        if arr.dtype.kind not in "biuf":
            raise ExportError(f"{where}: {type(obj).__name__} of {arr.dtype} is not JSON-able")
        if arr.ndim:
            return [_jsonable(v, f"{where}[{i}]") for i, v in enumerate(arr.tolist())]
        value = arr.item()
        if isinstance(value, float) and not math.isfinite(value):
            return "nan" if math.isnan(value) else ("inf" if value > 0 else "-inf")
        return value
    raise ExportError(f"{where}: {type(obj).__name__} is not JSON-able")


def _npz_bytes(arrays: dict[str, np.ndarray]) -> bytes:
    buf = io.BytesIO()
    np.savez(buf, **arrays)
    return buf.getvalue()


def actor_params_from_policy(policy: rp.Policy) -> tuple[dict, tuple[int, ...]]:
    """The inverse of ``export_policy``: flax params and hidden widths of a loaded export."""
    params = {
        layer.name: {"kernel": jnp.asarray(layer.kernel), "bias": jnp.asarray(layer.bias)}
        for layer in policy.layers
    }
    hidden = tuple(int(layer.kernel.shape[1]) for layer in policy.layers[:-1])
    return {"params": params}, hidden
