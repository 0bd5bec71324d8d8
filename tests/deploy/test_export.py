"""Export round trip, policy.json contents, numpy vs JAX parity, ONNX parity."""

from __future__ import annotations

import hashlib
import json
import math
import os
import sys

import jax
import numpy as np
import pytest

from advisor_jax.contract import spec
from advisor_jax.deploy.export import ExportError
from advisor_jax.deploy.golden import edge_case_observations
from advisor_jax.runner.policy import Layer, load_policy, mlp_forward
from advisor_jax.runner.policy_meta import config_hash
from tests.runner.runner_fakes import (
    CONFIG_META,
    ENV_META,
    export_test_actor,
    rollout_like_obs,
)


def test_round_trip_metadata(export_dir, policy, actor_params):
    meta = json.loads((export_dir / "policy.json").read_text())
    assert meta["schema_version"] == 2
    assert [(x["name"], x["in"], x["out"]) for x in meta["layers"]] == [
        ("hidden_0", 20, 48),
        ("hidden_1", 48, 48),
        ("head", 48, 2),
    ]
    assert [(h["name"], h["activation"], h["scale"]) for h in meta["heads"]] == [
        ("V", "sigmoid", 1.0),
        ("omega", "tanh", 2.0),
    ]
    assert meta["observation"]["names"] == list(spec.OBS_NAMES)
    assert meta["observation"]["units"] == list(spec.OBS_UNITS)
    assert meta["sensors"]["zone_start_deg"] == 90.0 and meta["sensors"]["n_zones"] == 16
    assert meta["sensors"]["lidar_range_offset"] == 0.22
    assert meta["control"] == {**meta["control"], "v_max": 1.0, "omega_max": 2.0, "dt": 0.05}
    assert meta["env"] == {**ENV_META, "bounds": list(ENV_META["bounds"])}
    assert meta["config"] == CONFIG_META
    assert meta["config_hash"] == config_hash(meta["config"], meta["env"])
    for name, key in (("policy.npz", "weights_sha256"), ("golden.npz", "golden_sha256")):
        assert hashlib.sha256((export_dir / name).read_bytes()).hexdigest() == meta[key]
    assert meta["onnx_sha256"] is None and not (export_dir / "policy.onnx").exists()
    assert not [f for f in os.listdir(export_dir) if f.startswith(".tmp")]
    # The weights are the actor's, in flax (in, out) layout, float32.
    with np.load(export_dir / "policy.npz") as npz:
        for name in ("hidden_0", "hidden_1", "head"):
            for p in ("kernel", "bias"):
                want = np.asarray(actor_params["params"][name][p], np.float32)
                np.testing.assert_array_equal(npz[f"{name}/{p}"], want)
                assert npz[f"{name}/{p}"].dtype == np.float32
    assert policy.v_max == 1.0 and policy.omega_max == 2.0 and policy.dt == 0.05
    assert policy.bounds == ENV_META["bounds"]


def test_golden_set_contents(export_dir, actor_params, jax_actor):
    with np.load(export_dir / "golden.npz") as g:
        obs, actions = g["obs"], g["actions"]
    assert obs.dtype == actions.dtype == np.float32
    assert obs.shape[0] >= 256 and obs.shape[1] == 20 and actions.shape == (len(obs), 2)
    np.testing.assert_array_equal(obs[:40], rollout_like_obs(40))  # caller's rows first
    edges = edge_case_observations(1.0)
    np.testing.assert_array_equal(obs[40 : 40 + len(edges)], edges)
    delta = obs[:, spec.OBS_GOAL_ANGLE]
    assert np.isclose(delta, math.pi).any() and np.isclose(delta, -math.pi).any()
    assert (obs[:, :16].max(axis=1) == 0).any() and (obs[:, :16].min(axis=1) == 1).any()
    assert (obs[:, 17] == 0).any() and (obs[:, 17] >= 10).any()
    assert (np.abs(obs[:, 18:]) >= 10).any()
    np.testing.assert_allclose(actions, jax_actor(actor_params, obs), atol=1e-6)


def test_numpy_matches_jitted_jax(policy, actor_params, jax_actor):
    rng = np.random.default_rng(5)
    random = np.concatenate(
        [
            rng.uniform(0, 1, (300, 16)),
            rng.uniform(-math.pi, math.pi, (300, 1)),
            rng.uniform(0, 8, (300, 1)),
            rng.normal(0, 1, (300, 2)),
        ],
        axis=1,
    ).astype(np.float32)
    for obs in (random, rollout_like_obs(300, seed=3), edge_case_observations(1.0)):
        want = jax_actor(actor_params, obs)
        assert np.abs(policy.act(obs) - want).max() <= 1e-5
        single = np.stack([policy.act(o) for o in obs[:32]])
        assert np.abs(single - want[:32]).max() <= 1e-5
        assert policy.act(obs[0]).shape == (2,)


def test_transposed_square_kernel_is_caught(policy, actor_params, jax_actor):
    """The square 48x48 kernel transposed keeps every shape but changes the actions."""
    layers = list(policy.layers)
    layers[1] = Layer("hidden_1", np.ascontiguousarray(layers[1].kernel.T), layers[1].bias)
    obs = rollout_like_obs(64, seed=9)
    assert np.abs(mlp_forward(layers, obs) - jax_actor(actor_params, obs)).max() > 1e-3


def test_export_rejects_bad_inputs(tmp_path, actor_params):
    out = tmp_path / "a"
    with pytest.raises(ExportError, match="expected"):
        export_test_actor(actor_params, out, actor_hidden=(48, 32))
    with pytest.raises(ExportError, match="layers"):
        export_test_actor(actor_params, out, actor_hidden=(48,))
    with pytest.raises(ExportError, match=r"golden_obs must have shape \[N, 20\]"):
        export_test_actor(actor_params, out, golden_obs=np.zeros((4, 19)))
    with pytest.raises(ExportError, match="NaN"):
        export_test_actor(actor_params, out, golden_obs=np.full((2, 20), np.nan))
    with pytest.raises(ExportError, match="omega_max"):
        env = {k: v for k, v in ENV_META.items() if k != "omega_max"}
        export_test_actor(actor_params, out, env_meta=env)
    with pytest.raises(ExportError, match="bounds"):
        export_test_actor(actor_params, out, env_meta={**ENV_META, "bounds": [1, 0, 0, 1]})
    with pytest.raises(ExportError, match="config_meta.bad"):
        export_test_actor(actor_params, out, config_meta={"bad": object()})
    bad = jax.tree_util.tree_map(np.array, actor_params)  # a writable copy
    bad["params"]["head"]["bias"][0] = np.nan
    with pytest.raises(ExportError, match="head.*NaN"):
        export_test_actor(bad, out, golden_obs=np.zeros((4, 20)))
    assert not (tmp_path / "a" / "policy.json").exists()


def test_metadata_is_strict_json(tmp_path, actor_params):
    config = {
        "hparams": {"advisor_episodes": np.float32(np.inf), "lr": np.float64(1e-4)},
        "widths": (600, 300),
        "seed": np.int64(3),
    }
    meta = export_test_actor(
        actor_params, tmp_path, config_meta=config, golden_obs=np.zeros((0, 20))
    )
    assert meta["config"] == {
        "hparams": {"advisor_episodes": "inf", "lr": 1e-4},
        "widths": [600, 300],
        "seed": 3,
    }
    assert meta["golden_size"] == 256
    json.loads((tmp_path / "policy.json").read_text(), parse_constant=pytest.fail)


def test_onnx_parity(tmp_path, actor_params, policy):
    onnx = pytest.importorskip("onnx")
    ort = pytest.importorskip("onnxruntime")
    meta = export_test_actor(actor_params, tmp_path, onnx=True)
    model = onnx.load(str(tmp_path / "policy.onnx"))
    assert max(o.version for o in model.opset_import if o.domain in ("", "ai.onnx")) <= 13
    assert model.ir_version <= 7
    assert (
        meta["onnx_sha256"] == hashlib.sha256((tmp_path / "policy.onnx").read_bytes()).hexdigest()
    )
    session = ort.InferenceSession(
        str(tmp_path / "policy.onnx"), providers=["CPUExecutionProvider"]
    )
    assert [i.name for i in session.get_inputs()] == ["obs"]
    with np.load(tmp_path / "golden.npz") as g:
        obs, actions = g["obs"], g["actions"]
    got = session.run(["action"], {"obs": obs})[0]
    assert got.shape == (len(obs), 2)
    assert np.abs(got - actions).max() <= 1e-5
    assert np.abs(got - policy.act(obs)).max() <= 1e-5
    # Re-exporting without ONNX removes the now stale model.
    export_test_actor(actor_params, tmp_path, golden_obs=np.zeros((0, 20)))
    assert not (tmp_path / "policy.onnx").exists()
    load_policy(tmp_path)


def test_onnx_missing_is_a_clear_error(tmp_path, actor_params, monkeypatch):
    monkeypatch.setitem(sys.modules, "onnx", None)  # makes `import onnx` fail
    with pytest.raises(ExportError, match=r"onnx=True needs .*pip install"):
        export_test_actor(actor_params, tmp_path, golden_obs=np.zeros((0, 20)), onnx=True)
    assert not (tmp_path / "policy.json").exists()
