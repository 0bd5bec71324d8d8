"""load_policy refuses every broken export with a message naming the file and the problem."""

from __future__ import annotations

import copy
import hashlib
import io
import json

import numpy as np
import pytest

from advisor_jax.contract import spec
from advisor_jax.runner.errors import PolicyError
from advisor_jax.runner.policy import load_policy
from advisor_jax.runner.policy_meta import config_hash, metadata_sha256


def _meta(d):
    return json.loads((d / "policy.json").read_text())


def _write_meta(d, meta, *, restamp: bool = True):
    """Writes policy.json; ``restamp`` also recomputes metadata_sha256, as an editor who knows
    the format would, so that the checks behind that hash are reached."""
    if restamp and "metadata_sha256" in meta:
        meta = {**meta, "metadata_sha256": metadata_sha256(meta)}
    (d / "policy.json").write_text(json.dumps(meta))


def _resave_npz(d, name, edit, *, update_sha: bool):
    """Rewrites an npz after ``edit(arrays)``; optionally fixes the sha in policy.json."""
    with np.load(d / name) as npz:
        arrays = {k: npz[k].copy() for k in npz.files}
    edit(arrays)
    buf = io.BytesIO()
    np.savez(buf, **arrays)
    (d / name).write_bytes(buf.getvalue())
    if update_sha:
        meta = _meta(d)
        key = "weights_sha256" if name == "policy.npz" else "golden_sha256"
        meta[key] = hashlib.sha256(buf.getvalue()).hexdigest()
        _write_meta(d, meta)


@pytest.mark.parametrize("name", ["policy.json", "policy.npz", "golden.npz"])
def test_missing_file(export_copy, name):
    (export_copy / name).unlink()
    with pytest.raises(PolicyError, match=rf"{name}: missing"):
        load_policy(export_copy)


def test_not_a_directory(tmp_path):
    with pytest.raises(PolicyError, match="not a directory"):
        load_policy(tmp_path / "nope")


def test_truncated_weights(export_copy):
    data = (export_copy / "policy.npz").read_bytes()
    (export_copy / "policy.npz").write_bytes(data[: len(data) // 2])
    with pytest.raises(PolicyError, match=r"policy.npz: sha256 .* does not match"):
        load_policy(export_copy)
    # Even with a matching hash a truncated archive is reported as corrupt, not a traceback.
    meta = _meta(export_copy)
    meta["weights_sha256"] = hashlib.sha256(data[: len(data) // 2]).hexdigest()
    _write_meta(export_copy, meta)
    with pytest.raises(PolicyError, match="policy.npz: corrupt or truncated npz"):
        load_policy(export_copy)


def test_tampered_weights(export_copy):
    def nudge(arrays):
        arrays["hidden_1/kernel"][3, 7] += 0.5

    _resave_npz(export_copy, "policy.npz", nudge, update_sha=False)
    with pytest.raises(PolicyError, match="policy.npz: sha256"):
        load_policy(export_copy)
    # A forger who also fixes the hash is caught by the golden set.
    _resave_npz(export_copy, "policy.npz", lambda a: None, update_sha=True)
    with pytest.raises(PolicyError, match=r"golden.npz: numpy policy differs .* by"):
        load_policy(export_copy)


def test_transposed_kernel_in_file_is_refused(export_copy):
    def transpose(arrays):
        arrays["hidden_1/kernel"] = np.ascontiguousarray(arrays["hidden_1/kernel"].T)

    _resave_npz(export_copy, "policy.npz", transpose, update_sha=True)
    with pytest.raises(PolicyError, match="golden.npz: numpy policy differs"):
        load_policy(export_copy)


def test_tampered_golden(export_copy):
    def nudge(arrays):
        arrays["actions"][10, 1] += 1e-3

    _resave_npz(export_copy, "golden.npz", nudge, update_sha=False)
    with pytest.raises(PolicyError, match="golden.npz: sha256"):
        load_policy(export_copy)
    _resave_npz(export_copy, "golden.npz", lambda a: None, update_sha=True)
    with pytest.raises(PolicyError, match=r"differs .* by 0.001 \(row 10"):
        load_policy(export_copy)


def test_nan_weights(export_copy):
    def poison(arrays):
        arrays["head/bias"][0] = np.nan

    _resave_npz(export_copy, "policy.npz", poison, update_sha=True)
    with pytest.raises(PolicyError, match="head/bias contains NaN"):
        load_policy(export_copy)


def test_wrong_dtype_and_shape(export_copy):
    def widen(arrays):
        arrays["hidden_0/bias"] = arrays["hidden_0/bias"].astype(np.float64)

    _resave_npz(export_copy, "policy.npz", widen, update_sha=True)
    with pytest.raises(PolicyError, match=r"hidden_0/bias is float64\[48\].*float32\[48\]"):
        load_policy(export_copy)


def test_layer_sizes_must_match_json(export_copy):
    meta = _meta(export_copy)
    meta["layers"][1]["out"] = 47
    _write_meta(export_copy, meta)
    with pytest.raises(PolicyError, match="hidden_1/kernel is float32\\[48, 48\\]"):
        load_policy(export_copy)


@pytest.mark.parametrize("version", [3, 0, None, "1", True])
def test_wrong_schema(export_copy, version):
    meta = _meta(export_copy)
    meta["schema_version"] = version
    _write_meta(export_copy, meta)
    with pytest.raises(PolicyError, match="policy.json: unsupported schema_version"):
        load_policy(export_copy)


def test_edited_metadata_breaks_config_hash(export_copy):
    meta = _meta(export_copy)
    meta["env"]["bounds"] = [-10, 10, -10, 10]
    _write_meta(export_copy, meta)
    with pytest.raises(PolicyError, match="config_hash does not match"):
        load_policy(export_copy)
    meta["config_hash"] = config_hash(meta["config"], meta["env"])
    _write_meta(export_copy, meta)
    assert load_policy(export_copy).bounds == (-10, 10, -10, 10)


@pytest.mark.parametrize(
    ("section", "key", "value", "message"),
    [
        ("sensors", "zone_start_deg", 67.5, "zone definition"),
        ("observation", "names", ["x"] * 20, "observation layout"),
        ("control", "omega_max", -1.0, "omega_max=-1.0 must be a positive"),
        ("control", "dt", None, "dt=None must be a positive"),
    ],
)
def test_layout_and_control_checks(export_copy, section, key, value, message):
    meta = _meta(export_copy)
    meta[section][key] = value
    _write_meta(export_copy, meta)
    with pytest.raises(PolicyError, match=message):
        load_policy(export_copy)


def test_garbage_json(export_copy):
    (export_copy / "policy.json").write_text("{not json")
    with pytest.raises(PolicyError, match="policy.json: not valid JSON"):
        load_policy(export_copy)
    (export_copy / "policy.json").write_text("[1, 2]")
    with pytest.raises(PolicyError, match="top level must be a JSON object"):
        load_policy(export_copy)


def test_act_validates_observations(policy):
    with pytest.raises(PolicyError, match=r"shape \[20\] or \[N, 20\]"):
        policy.act(np.zeros(19))
    obs = np.zeros(20)
    obs[17] = np.nan
    with pytest.raises(PolicyError, match="non-finite values in d"):
        policy.act(obs)
    out = policy.act(np.zeros((5, 20)))
    assert out.dtype == np.float32 and out.shape == (5, 2)
    # The fast check (one dot product) catches every non-finite value in every position,
    # alone or with its opposite, and lets huge finite values (its overflow) through.
    for i in range(20):
        for bad in (np.nan, np.inf, -np.inf):
            obs = np.zeros(20, np.float32)
            obs[i] = bad
            with pytest.raises(PolicyError, match=spec.OBS_NAMES[i]):
                policy.act(obs)
            with pytest.raises(PolicyError, match=spec.OBS_NAMES[i]):
                policy.act(np.stack([np.zeros(20, np.float32), obs]))
    huge = np.full(20, 1e20, np.float32)
    assert np.isinf(np.vdot(huge, huge))  # the fast check overflows; the slow one lets it go
    assert np.isfinite(policy.act(huge)).all() and np.isfinite(policy.act(-huge)).all()
    assert ((out[:, 0] >= 0) & (out[:, 0] <= 1) & (np.abs(out[:, 1]) <= 1)).all()


# Issue 20, case 1: every field of policy.json that changes what the car does is verified.
# (section, key, edited value); the test export was trained with v_max 1, omega_max 2,
# dt 0.05, lidar offset 0.22 and max_range 1.
CAR_FIELDS = [
    ("control", "v_max", 5.0),
    ("control", "omega_max", 30.0),
    ("control", "dt", 0.5),
    ("sensors", "lidar_range_offset", 0.0),
    ("sensors", "max_range", 2.0),
    ("observation", "max_range", 0.5),
    ("heads", 1, {"name": "omega", "activation": "tanh", "range": [-1.0, 1.0], "scale": 9.0}),
    ("control", "action_low", [0.0, -2.0]),
    ("sensors", "sonar_directions_deg", [0.0] * 16),
]


def _edit(meta, section, key, value):
    meta[section][key] = value
    return meta


def test_export_covers_its_metadata_with_a_hash(export_copy):
    meta = _meta(export_copy)
    assert meta["schema_version"] == 2
    assert meta["metadata_sha256"] == metadata_sha256(meta)
    meta["created"] = "2000-01-01T00:00:00+00:00"  # even a field the car ignores
    _write_meta(export_copy, meta, restamp=False)
    with pytest.raises(PolicyError, match="metadata_sha256 .* policy.json was edited"):
        load_policy(export_copy)


@pytest.mark.parametrize(("section", "key", "value"), CAR_FIELDS)
def test_edited_car_field_is_refused(export_copy, section, key, value):
    meta = _edit(_meta(export_copy), section, key, value)
    _write_meta(export_copy, meta, restamp=False)
    with pytest.raises(PolicyError, match="policy.json was edited after export"):
        load_policy(export_copy)
    # With the file hash recomputed, the cross-check against the trained env still refuses.
    _write_meta(export_copy, meta)
    with pytest.raises(PolicyError, match="differs from"):
        load_policy(export_copy)


@pytest.mark.parametrize(("section", "key", "value"), CAR_FIELDS)
def test_schema_1_export_is_checked_against_training(export_copy, section, key, value):
    """A schema-1 export (no metadata_sha256) still loads, and its car fields are checked."""
    meta = _meta(export_copy)
    meta["schema_version"] = 1
    del meta["metadata_sha256"]
    _write_meta(export_copy, meta)
    assert load_policy(export_copy).v_max == 1.0
    _write_meta(export_copy, _edit(meta, section, key, value))
    with pytest.raises(PolicyError, match="differs from"):
        load_policy(export_copy)


def test_limit_beyond_training_names_both_values(export_copy):
    original = _meta(export_copy)
    _write_meta(export_copy, _edit(copy.deepcopy(original), "control", "v_max", 5.0))
    with pytest.raises(
        PolicyError,
        match=r"control.v_max=5.0 differs from v_max=1.0 the actor was trained with "
        r"\(env.v_max\) \(beyond the trained limit\)",
    ):
        load_policy(export_copy)
    _write_meta(export_copy, _edit(original, "control", "dt", 0.5))
    with pytest.raises(PolicyError, match=r"control.dt=0.5 differs from dt=0.05"):
        load_policy(export_copy)


def test_committed_schema_1_export_still_loads():
    """results/policy_physical_atd3_afdp predates metadata_sha256 and passes every check."""
    from pathlib import Path

    policy = load_policy(Path(__file__).parents[2] / "results" / "policy_physical_atd3_afdp")
    assert policy.meta["schema_version"] == 1
    limits = (policy.v_max, policy.omega_max, policy.dt, policy.range_offset)
    assert limits == (1.0, 3.0, 0.05, 0.22)
