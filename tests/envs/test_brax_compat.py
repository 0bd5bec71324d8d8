"""envs/brax_compat.py: jax.device_put_replicated for brax 0.14 on jax >= 0.10 (brax #671).

When a brax release no longer calls the function, ``test_brax_still_calls_it`` fails: then
delete envs/brax_compat.py, its call in envs/brax_env.py and this file.
"""

from __future__ import annotations

import os
import subprocess
import sys
import textwrap
from pathlib import Path

import jax
import numpy as np
import pytest

from envs import brax_compat

ROOT = Path(__file__).resolve().parents[2]


def test_brax_still_calls_it():
    assert brax_compat.brax_calls_it(), (
        "the installed brax no longer calls jax.device_put_replicated: delete "
        "envs/brax_compat.py, its install() in envs/brax_env.py and this test"
    )


def test_installs_only_what_is_missing_and_needed(monkeypatch):
    sentinel = object()
    monkeypatch.setattr(jax, "device_put_replicated", sentinel, raising=False)
    assert brax_compat.install() is False  # jax has it: left alone
    assert jax.device_put_replicated is sentinel
    monkeypatch.delattr(jax, "device_put_replicated")
    monkeypatch.setattr(brax_compat, "brax_calls_it", lambda: False)
    assert brax_compat.install() is False  # brax does not call it: nothing installed
    assert not hasattr(jax, "device_put_replicated")
    monkeypatch.setattr(brax_compat, "brax_calls_it", lambda: True)
    assert brax_compat.install() is True
    assert jax.device_put_replicated is brax_compat.device_put_replicated


def test_replicates_a_pytree_onto_one_device():
    tree = {"a": np.arange(3.0), "b": (np.int32(7),)}
    out = brax_compat.device_put_replicated(tree, jax.local_devices()[:1])
    np.testing.assert_array_equal(out["a"], [[0.0, 1.0, 2.0]])
    assert out["b"][0].shape == (1,) and int(out["b"][0][0]) == 7
    with pytest.raises(ValueError, match="at least one device"):
        brax_compat.device_put_replicated(tree, [])


def test_replicas_feed_pmap_on_two_devices():
    """What brax does with the result: pmap over it, one copy per device."""
    script = textwrap.dedent(
        """
        import jax, numpy as np
        from envs import brax_compat
        x = brax_compat.device_put_replicated({"w": np.arange(4.0)}, jax.local_devices())
        assert x["w"].shape == (2, 4), x["w"].shape
        assert {s.device for s in x["w"].addressable_shards} == set(jax.local_devices())
        y = jax.pmap(lambda t: t["w"] * 2 + jax.lax.axis_index("i"), axis_name="i")(x)
        np.testing.assert_array_equal(y, [[0, 2, 4, 6], [1, 3, 5, 7]])
        print("OK")
        """
    )
    env = {
        **os.environ,
        "XLA_FLAGS": "--xla_force_host_platform_device_count=2",
        "JAX_PLATFORMS": "cpu",
        "PYTHONPATH": str(ROOT),
    }
    proc = subprocess.run([sys.executable, "-c", script], capture_output=True, text=True,
                          env=env, cwd=ROOT, timeout=300)  # fmt: skip
    assert proc.returncode == 0 and "OK" in proc.stdout, proc.stderr[-2000:]
