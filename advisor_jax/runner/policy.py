"""Loading, verifying and running an exported actor with numpy only (paper §5.3, Fig. 4a).

An export directory (written by ``advisor_jax.deploy.export``) holds::

    policy.json   metadata: schema_version, layers, heads, observation/sensor layout,
                  control scaling, env and config, config_hash, weights_sha256, golden_sha256,
                  metadata_sha256 (schema 2)
    policy.npz    float32 "<layer>/kernel" [in, out] (flax layout) and "<layer>/bias" [out]
    golden.npz    obs [N, 20] and the JIT-compiled JAX actor's actions [N, 2]

``load_policy`` refuses to return a policy unless every check passes: schema version, the
sha256 of policy.json's own contents (``metadata_sha256``, schema 2), sha256 of both npz files,
config hash, layer names/shapes/dtypes against the json, finite weights, the observation and
zone layout against ``spec.py``, every field the car acts on (``control``, the heads' scales,
``sensors``, ``observation.max_range``) against the values the actor was trained with
(``trained_values``: the hash-covered ``env``), and the numpy MLP reproducing every golden
action within ``GOLDEN_TOLERANCE`` (max abs). The forward pass is the actor's maths::

    x = obs;  x = relu(x @ W_i + b_i) for each hidden layer;  z = x @ W_head + b_head
    action = [sigmoid(z_0), tanh(z_1)]          # (V, ω), normalised

computed in float32, for one observation [20] or a batch [N, 20].
"""

from __future__ import annotations

import dataclasses
import io
import json
import math
import os
import zipfile
from collections.abc import Sequence
from typing import Any

import numpy as np

from advisor_jax.contract import spec
from advisor_jax.runner import signature
from advisor_jax.runner.errors import PolicyError
from advisor_jax.runner.policy_meta import (
    check_meta,
    fail,
    sha256_bytes,
)

POLICY_JSON = "policy.json"
POLICY_NPZ = "policy.npz"
GOLDEN_NPZ = "golden.npz"
POLICY_ONNX = "policy.onnx"
GOLDEN_TOLERANCE = 1e-5
_SIGMOID_CLIP = 80.0  # |z| beyond this saturates sigmoid in float32; avoids exp overflow
# The control cycle calls these once per cycle (bench_runner.py): bound once, and a float32
# zero so that np.maximum does not convert a Python float on every call.
_matmul, _add, _maximum, _vdot = np.matmul, np.add, np.maximum, np.vdot
_ZERO32 = np.zeros((), np.float32)


@dataclasses.dataclass(frozen=True)
class Layer:
    """One dense layer: ``x @ kernel + bias``; kernel [in, out] float32, bias [out]."""

    name: str
    kernel: np.ndarray
    bias: np.ndarray


def mlp_forward(layers: Sequence[Layer], obs: np.ndarray) -> np.ndarray:
    """Actor forward pass in float32: [..., 20] → [..., 2] = (V ∈ [0, 1], ω ∈ [-1, 1])."""
    x = obs
    for layer in layers[:-1]:
        x = _matmul(x, layer.kernel)  # new array: never writes into the caller's obs
        _add(x, layer.bias, out=x)
        _maximum(x, _ZERO32, out=x)
    head = layers[-1]
    z = _matmul(x, head.kernel)
    _add(z, head.bias, out=z)
    if z.ndim == 1:  # one observation (the control loop): two scalars, no array round trips
        z0, z1 = z.tolist()
        v = 1.0 / (1.0 + math.exp(-min(max(z0, -_SIGMOID_CLIP), _SIGMOID_CLIP)))
        return np.array((v, math.tanh(z1)), dtype=np.float32)
    out = np.empty_like(z)
    out[..., 0] = 1.0 / (1.0 + np.exp(-np.clip(z[..., 0], -_SIGMOID_CLIP, _SIGMOID_CLIP)))
    out[..., 1] = np.tanh(z[..., 1])
    return out


@dataclasses.dataclass(frozen=True)
class Policy:
    """A verified actor plus its export metadata (``meta`` is policy.json)."""

    layers: tuple[Layer, ...]
    meta: dict
    directory: str

    def act(self, obs: np.ndarray) -> np.ndarray:
        """Normalised action (V, ω): [20] → [2] or [N, 20] → [N, 2], float32.

        Raises PolicyError on a wrong shape or a non-finite observation.
        """
        x = obs
        if not (type(x) is np.ndarray and x.dtype == np.float32):
            x = np.asarray(obs, dtype=np.float32)
        if x.ndim not in (1, 2) or x.shape[-1] != spec.OBS_SIZE:
            raise PolicyError(
                f"observation must have shape [{spec.OBS_SIZE}] or [N, {spec.OBS_SIZE}], "
                f"got {list(x.shape)}"
            )
        # One dot product finds NaN and inf (huge finite values may overflow it: re-checked).
        if not math.isfinite(_vdot(x, x)) and not np.isfinite(x).all():
            bad = np.flatnonzero(~np.isfinite(x.reshape(-1, spec.OBS_SIZE)).all(axis=0))
            names = ", ".join(spec.OBS_NAMES[i] for i in bad)
            raise PolicyError(f"observation has non-finite values in {names}")
        return mlp_forward(self.layers, x)

    @property
    def v_max(self) -> float:
        return float(self.meta["control"]["v_max"])

    @property
    def omega_max(self) -> float:
        return float(self.meta["control"]["omega_max"])

    @property
    def dt(self) -> float:
        return float(self.meta["control"]["dt"])

    @property
    def max_range(self) -> float:
        return float(self.meta["observation"]["max_range"])

    @property
    def range_offset(self) -> float:
        return float(self.meta["sensors"]["lidar_range_offset"])

    @property
    def env(self) -> dict:
        return self.meta["env"]

    @property
    def bounds(self) -> tuple[float, float, float, float] | None:
        b = self.env.get("bounds")
        return None if b is None else tuple(float(v) for v in b)

    @property
    def weights_sha256(self) -> str:
        return self.meta["weights_sha256"]


def _read_bytes(path: str) -> bytes:
    try:
        with open(path, "rb") as f:
            return f.read()
    except FileNotFoundError:
        raise fail(path, "missing (not an export directory, or an incomplete export)") from None
    except OSError as e:
        raise fail(path, f"cannot be read ({e.strerror or e})") from None


def _load_npz(path: str, data: bytes, expected_sha: Any) -> dict[str, np.ndarray]:
    actual = sha256_bytes(data)
    if actual != expected_sha:
        raise fail(
            path,
            f"sha256 {actual[:16]}… does not match policy.json's {str(expected_sha)[:16]}… "
            "(file modified, truncated or from another export)",
        )
    try:
        with np.load(io.BytesIO(data), allow_pickle=False) as npz:
            return {k: np.asarray(npz[k]) for k in npz.files}
    except (zipfile.BadZipFile, ValueError, OSError, EOFError, KeyError) as e:
        raise fail(path, f"corrupt or truncated npz ({type(e).__name__}: {e})") from None


def _build_layers(json_path: str, npz_path: str, meta: dict, arrays: dict) -> tuple[Layer, ...]:
    specs = meta["layers"]
    if not isinstance(specs, list) or len(specs) < 2:
        raise fail(json_path, "layers must list at least one hidden layer and the head")
    names = [s.get("name") if isinstance(s, dict) else None for s in specs]
    expected_names = [f"hidden_{i}" for i in range(len(specs) - 1)] + ["head"]
    if names != expected_names:
        raise fail(json_path, f"layer names {names} should be {expected_names}")
    expected_keys = {f"{n}/{p}" for n in names for p in ("kernel", "bias")}
    if set(arrays) != expected_keys:
        raise fail(npz_path, f"arrays {sorted(arrays)} do not match layers {names}")
    layers, width = [], spec.OBS_SIZE
    for i, s in enumerate(specs):
        name, n_in, n_out = s["name"], s.get("in"), s.get("out")
        activation = "relu" if i < len(specs) - 1 else "heads"
        if s.get("activation") != activation or n_in != width:
            raise fail(json_path, f"layer {name}: expected in={width}, activation={activation}")
        kernel, bias = arrays[f"{name}/kernel"], arrays[f"{name}/bias"]
        for arr, shape, what in ((kernel, (n_in, n_out), "kernel"), (bias, (n_out,), "bias")):
            if arr.dtype != np.float32 or arr.shape != shape:
                raise fail(
                    npz_path,
                    f"{name}/{what} is {arr.dtype}{list(arr.shape)}, policy.json says "
                    f"float32{list(shape)}",
                )
            if not np.isfinite(arr).all():
                raise fail(npz_path, f"{name}/{what} contains NaN or inf")
        layers.append(Layer(name, np.ascontiguousarray(kernel), np.ascontiguousarray(bias)))
        width = n_out
    if width != spec.ACTION_SIZE:
        raise fail(json_path, f"head has {width} outputs, expected {spec.ACTION_SIZE}")
    return tuple(layers)


def verify_golden(path: str, layers: Sequence[Layer], golden: dict) -> None:
    """Raises PolicyError unless the numpy MLP reproduces ``golden["actions"]`` (1e-5)."""
    obs, actions = golden.get("obs"), golden.get("actions")
    if obs is None or actions is None:
        raise fail(path, f"needs arrays 'obs' and 'actions', has {sorted(golden)}")
    if obs.ndim != 2 or obs.shape[1] != spec.OBS_SIZE or actions.shape != (len(obs), 2):
        raise fail(path, f"bad shapes obs {list(obs.shape)}, actions {list(actions.shape)}")
    if len(obs) == 0 or obs.dtype != np.float32 or actions.dtype != np.float32:
        raise fail(path, "obs and actions must be non-empty float32 arrays")
    if not (np.isfinite(obs).all() and np.isfinite(actions).all()):
        raise fail(path, "contains NaN or inf")
    # Both the batched path (gemm) and the single-observation path the loop uses (gemv).
    err = np.abs(mlp_forward(layers, obs) - actions).max(axis=1)
    pairs = zip(obs[:16], actions[:16], strict=True)
    single = [np.abs(mlp_forward(layers, o) - a).max() for o, a in pairs]
    worst = int(np.argmax(err))
    max_err = max(float(err[worst]), max(single))
    if not max_err <= GOLDEN_TOLERANCE:
        raise fail(
            path,
            f"numpy policy differs from the exported JAX actions by {max_err:.3g} "
            f"(row {worst}; tolerance {GOLDEN_TOLERANCE:g}): weights or maths do not match",
        )


def load_policy(directory: str | os.PathLike, verify_key: bytes | None = None) -> Policy:
    """Reads and verifies an export directory; raises PolicyError on any problem.

    With ``verify_key`` the export must carry a valid signature (``signature.py``) of the
    very bytes of policy.json that are then parsed and checked."""
    directory = os.fspath(directory)
    if not os.path.isdir(directory):
        raise PolicyError(f"{directory}: not a directory (expected an export directory)")
    json_path = os.path.join(directory, POLICY_JSON)
    json_bytes = _read_bytes(json_path)
    if verify_key is not None:
        sig_path = os.path.join(directory, signature.SIGNATURE_FILE)
        sig_bytes = _read_bytes(sig_path) if os.path.lexists(sig_path) else None
        signature.verify(sig_path, sig_bytes, json_bytes, verify_key)
    try:
        meta = json.loads(json_bytes.decode("utf-8"))
    except (UnicodeDecodeError, json.JSONDecodeError, RecursionError) as e:
        raise fail(json_path, f"not valid JSON ({type(e).__name__}: {e})") from None
    check_meta(json_path, meta)
    npz_path = os.path.join(directory, POLICY_NPZ)
    arrays = _load_npz(npz_path, _read_bytes(npz_path), meta["weights_sha256"])
    layers = _build_layers(json_path, npz_path, meta, arrays)
    golden_path = os.path.join(directory, GOLDEN_NPZ)
    golden = _load_npz(golden_path, _read_bytes(golden_path), meta["golden_sha256"])
    verify_golden(golden_path, layers, golden)
    return Policy(layers=layers, meta=meta, directory=directory)
