"""Advisors as plug-ins (``agent/advisors.py``): the rule under the interface, a user's
module:function, the registry, the identity hash, and the checks that name a bad advisor."""

from __future__ import annotations

import sys

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from advisor_jax.agent.advisor import AdvisorParams, advisor_action
from advisor_jax.agent.advisors import (
    Advisor,
    AdvisorPlugin,
    check_advisor,
    plugin_for,
    register_advisor,
    tree_sha256,
)


def _observations(n: int, seed: int = 0) -> np.ndarray:
    rng = np.random.default_rng(seed)
    obs = np.zeros((n, 20), np.float32)
    obs[:, :16] = rng.choice([1.0, 0.15, 0.3, 0.45, 0.55], (n, 16))
    obs[:, 16] = rng.uniform(-np.pi, np.pi, n)
    obs[:, 17] = rng.uniform(0.0, 5.0, n)
    return obs


class _Arena:  # what a plugin's params function reads of an arena
    obstacle_threshold = 0.6


def test_the_rule_under_the_interface_is_algorithm_a1():
    plugin, kind, source = plugin_for("rule")
    assert kind == "builtin" and source is None
    params = plugin.params(_Arena())
    assert tree_sha256(params) == tree_sha256(AdvisorParams(obstacle_threshold=0.6))
    obs = jnp.asarray(_observations(64))
    got = jax.vmap(plugin.apply, in_axes=(None, 0))(params, obs)
    want = jax.vmap(advisor_action, in_axes=(0, None))(obs, params)
    np.testing.assert_array_equal(np.asarray(got), np.asarray(want))


def test_params_are_a_pytree_that_vmaps():
    plugin, _, _ = plugin_for("rule")
    stacked = jax.tree.map(
        lambda x: jnp.stack([jnp.asarray(x)] * 2), AdvisorParams(obstacle_threshold=0.5)
    )
    stacked = stacked.replace(m3=jnp.array([1.0, 3.0]))
    obs = jnp.asarray(_observations(1)[0]).at[:4].set(0.1)  # an obstacle on the left
    out = np.asarray(jax.vmap(plugin.apply, in_axes=(0, None))(stacked, obs))
    assert out[1, 1] < out[0, 1] < 0  # a larger m3 turns harder (to the right)


MODULE = """
import jax.numpy as jnp

def straight(params, obs):
    return jnp.stack([params["speed"], 0.0 * obs[16]])

def no_params(params, obs):
    return jnp.zeros(2) + 0.0 * obs[0]

def branchy(params, obs):
    if obs[0] > 0.5:
        return jnp.array([1.0, 0.0])
    return jnp.array([0.0, 0.0])

def three(params, obs):
    return jnp.zeros(3)

def blows_up(params, obs):
    return jnp.stack([1.0 / (obs[17] - obs[17]), 0.0])

def as_int(params, obs):
    return jnp.zeros(2, jnp.int32)

def fails(params, obs):
    return obs["goal"]

from advisor_jax.agent.advisors import AdvisorPlugin
plugin = AdvisorPlugin(straight, params={"speed": jnp.float32(0.25)})
not_a_function = 3
"""


@pytest.fixture
def user_module(tmp_path, monkeypatch):
    (tmp_path / "user_advisors.py").write_text(MODULE)
    monkeypatch.chdir(tmp_path)
    yield "user_advisors"
    sys.modules.pop("user_advisors", None)
    if str(tmp_path) in sys.path:
        sys.path.remove(str(tmp_path))


def _advisor(spec: str) -> Advisor:
    plugin, kind, source = plugin_for(spec)
    return Advisor(spec, kind, plugin.apply, plugin.params, source)


def test_a_module_function_from_the_current_directory(user_module):
    advisor = _advisor(f"{user_module}:plugin")
    assert advisor.kind == "function" and len(advisor.source_sha256) == 64
    action = advisor.apply(advisor.params, jnp.zeros(20))
    np.testing.assert_allclose(np.asarray(action), [0.25, 0.0])
    plain = _advisor(f"{user_module}:no_params")  # a plain function: params {}
    assert plain.params == {}
    check_advisor(plain, _observations(8))


@pytest.mark.parametrize(
    "attribute, message",
    [
        ("branchy", r"'user_advisors:branchy' is not jittable: TracerBoolConversionError"),
        ("three", r"'user_advisors:three' returned ShapeDtypeStruct \(3,\) float32 for one"),
        ("blows_up", r"'user_advisors:blows_up' returned the non-finite action \[inf, 0.0\]"),
        ("as_int", r"'user_advisors:as_int' returned ShapeDtypeStruct \(2,\) int32"),
        ("fails", r"'user_advisors:fails' fails on an observation of shape \(20,\): "),
    ],
)
def test_a_bad_advisor_is_named_with_what_it_returned(user_module, attribute, message):
    with pytest.raises(ValueError, match=message):
        check_advisor(_advisor(f"{user_module}:{attribute}"), _observations(8))


def test_bad_module_specs_are_named(user_module):
    with pytest.raises(ValueError, match="no module named 'no_such_module'"):
        plugin_for("no_such_module:f")
    with pytest.raises(ValueError, match="module user_advisors has no 'missing'"):
        plugin_for(f"{user_module}:missing")
    with pytest.raises(ValueError, match="is a int, not a function"):
        plugin_for(f"{user_module}:not_a_function")
    assert plugin_for("runs/teacher:0") is None  # a path: training/advisor_source's


def test_register_advisor_by_name():
    plugin = register_advisor("test_constant", lambda p, obs: p + 0.0 * obs[:2], jnp.ones(2))
    found, kind, _ = plugin_for("test_constant")
    assert found is plugin and kind == "registered"
    with pytest.raises(ValueError, match="built in"):
        register_advisor("rule", plugin.apply)
    with pytest.raises(ValueError, match="advisor name 'a b'"):
        register_advisor("a b", plugin.apply)


def test_the_identity_hash_follows_the_parameters():
    a = tree_sha256(AdvisorParams())
    assert a == tree_sha256(AdvisorParams())
    assert a != tree_sha256(AdvisorParams(obstacle_threshold=0.6))
    assert tree_sha256({"w": np.zeros(2, np.float32)}) != tree_sha256({"w": np.zeros(2)})
    record = Advisor("x", "function", None, {"w": 1.0}, "abc").record()
    assert record == {"spec": "x", "kind": "function", "params_sha256": tree_sha256({"w": 1.0}),
                      "source_sha256": "abc"}  # fmt: skip
    assert isinstance(AdvisorPlugin(lambda p, o: o).params, dict)
