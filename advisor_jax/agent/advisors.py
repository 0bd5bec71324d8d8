"""Advisors as plug-ins: one interface, a registry of names, and the checks that name a bad one.

The paper's architecture takes "any rule-based or learned controller" as the advisor. Here an
advisor is a **jittable function of one observation** with parameters that are a pytree::

    apply(params, obs) -> action
        obs:    [20] float32, laid out as in ``contract/spec.py`` (P1..P16, δ, d, v_x, v_y)
        action: [2]  (V, ω) in normalised units, V in [0, 1], ω in [-1, 1]
        params: any pytree (a dict of arrays, a flax struct, a network's weights, ``{}``)

Whatever the advisor returns is clipped to the action box. The trainer vmaps ``apply`` over
environments and agents, so it must use ``jnp`` operations on the observation (``jnp.where``
or ``lax.cond`` for a choice, never a Python ``if`` on a value of ``obs``).

Where an advisor comes from (``plugin_for``; trained policies in ``training/advisor_source``):

* a registered name: ``rule`` (the paper's Algorithm A1, ``agent/advisor.py``, with the
  arena's T_o), or any name given to ``register_advisor``;
* ``module:attribute``: an ``AdvisorPlugin`` or a plain function ``(params, obs) -> action``
  (params ``{}``) importable from Python (the current directory is searched too).

An ``AdvisorPlugin``'s ``params`` may be a function of the arena (``envs.NavEnv``) returning
the pytree, as the rule's T_o depends on the arena. ``check_advisor`` traces a resolved
advisor and runs it on sample observations: a function that is not jittable, returns another
shape or a non-finite action is refused with a message naming the advisor and what it
returned. ``docs/advisors.md`` has a complete example.
"""

from __future__ import annotations

import dataclasses
import hashlib
import importlib
import inspect
import os
import re
import sys
from collections.abc import Callable
from typing import Any

import jax
import jax.numpy as jnp
import numpy as np

from advisor_jax.agent.advisor import advisor_action, arena_advisor
from advisor_jax.contract import spec

AdvisorApply = Callable[[Any, jax.Array], jax.Array]  # (params, obs [20]) -> action [2]

DEFAULT = "rule"
"""The advisor of every run that names none: the paper's Algorithm A1."""


@dataclasses.dataclass(frozen=True)
class AdvisorPlugin:
    """A user's advisor: the function and its parameters (a pytree, or a function of the
    arena, ``envs.NavEnv``, that returns one)."""

    apply: AdvisorApply
    params: Any = dataclasses.field(default_factory=dict)


@dataclasses.dataclass(frozen=True)
class Advisor:
    """An advisor resolved for one arena: what the trainer, the evaluation and run.json use."""

    spec: str  # as given: "rule", "my_advisors:wall_follower", "runs/teacher:0", "policy/"
    kind: str  # "builtin", "registered", "function", "run" or "export"
    apply: AdvisorApply
    params: Any
    source_sha256: str | None = None  # of the function's source (user functions)
    origin: dict = dataclasses.field(default_factory=dict)  # a trained policy's provenance

    def record(self) -> dict:
        """Its identity for run.json: spec, kind, the sha256 of its parameters (and of the
        function's source, and a trained policy's origin, where there is one)."""
        out = {"spec": self.spec, "kind": self.kind, "params_sha256": tree_sha256(self.params)}
        if self.source_sha256 is not None:
            out["source_sha256"] = self.source_sha256
        if self.origin:
            out["origin"] = dict(self.origin)
        return out


def _rule(params, obs: jax.Array) -> jax.Array:
    """The paper's Algorithm A1 (``agent/advisor.py``) under the plug-in signature."""
    return advisor_action(obs, params)


_BUILTIN: dict[str, AdvisorPlugin] = {"rule": AdvisorPlugin(_rule, arena_advisor)}
_REGISTERED: dict[str, AdvisorPlugin] = {}


def register_advisor(name: str, apply: AdvisorApply, params: Any = None) -> AdvisorPlugin:
    """Makes ``name`` an advisor (``--advisor name`` in a program that imported the
    registration); returns its plugin. ``params``: a pytree or a function of the arena."""
    if not re.fullmatch(r"[A-Za-z_][\w.-]*", name or ""):
        raise ValueError(f"advisor name {name!r}: use letters, digits, '_', '-' and '.'")
    if name in _BUILTIN:
        raise ValueError(f"advisor name {name!r} is built in; choose another")
    if not callable(apply):
        raise ValueError(f"advisor {name!r}: apply must be a function (params, obs) -> action")
    plugin = AdvisorPlugin(apply, {} if params is None else params)
    _REGISTERED[name] = plugin
    return plugin


def registered_names() -> tuple[str, ...]:
    return (*_BUILTIN, *_REGISTERED)


_MODULE_SPEC = re.compile(r"[A-Za-z_][\w]*(\.[A-Za-z_][\w]*)*:[A-Za-z_][\w]*(\.[A-Za-z_][\w]*)*")


def is_module_spec(text: str) -> bool:
    """Whether ``text`` reads as ``module.path:attribute``."""
    return bool(_MODULE_SPEC.fullmatch(text))


def plugin_for(name: str) -> tuple[AdvisorPlugin, str, str | None] | None:
    """(plugin, kind, source sha256) of a registered name or ``module:attribute``; None for
    anything else (a trained policy's path: ``training/advisor_source``)."""
    if name in _BUILTIN:
        return _BUILTIN[name], "builtin", None
    if name in _REGISTERED:
        return _REGISTERED[name], "registered", _source_sha256(_REGISTERED[name].apply)
    if not is_module_spec(name):
        return None
    module_name, _, attribute = name.partition(":")
    module = _import(module_name, name)
    target: Any = module
    for part in attribute.split("."):
        if not hasattr(target, part):
            raise ValueError(f"advisor {name!r}: module {module_name} has no {attribute!r}")
        target = getattr(target, part)
    if isinstance(target, AdvisorPlugin):
        plugin = target
    elif callable(target):
        plugin = AdvisorPlugin(target)
    else:
        raise ValueError(
            f"advisor {name!r} is a {type(target).__name__}, not a function (params, obs) -> "
            "action or an AdvisorPlugin"
        )
    return plugin, "function", _source_sha256(plugin.apply)


def _import(module_name: str, spec_text: str):
    """Imports ``module_name``; the current directory is searched last (a console script's
    path does not hold it)."""
    if os.getcwd() not in sys.path and "" not in sys.path:
        sys.path.append(os.getcwd())
    try:
        return importlib.import_module(module_name)
    except ModuleNotFoundError as e:
        if e.name and module_name.startswith(e.name):
            raise ValueError(
                f"advisor {spec_text!r}: no module named {e.name!r} (on PYTHONPATH or in the "
                "current directory)"
            ) from None
        raise


def _source_sha256(function: Callable) -> str | None:
    try:
        text = inspect.getsource(function)
    except (OSError, TypeError):
        return None
    return hashlib.sha256(text.encode()).hexdigest()


def resolve_plugin(plugin: AdvisorPlugin, env) -> Any:
    """The plugin's parameters for arena ``env``."""
    return plugin.params(env) if callable(plugin.params) else plugin.params


def tree_sha256(tree: Any) -> str:
    """sha256 of a pytree: its structure and every leaf's dtype, shape and bytes."""
    digest = hashlib.sha256(str(jax.tree_util.tree_structure(tree)).encode())
    for leaf in jax.tree_util.tree_leaves(tree):
        array = np.ascontiguousarray(np.asarray(leaf))
        digest.update(f"{array.dtype.str}{array.shape}".encode())
        digest.update(array.tobytes())
    return digest.hexdigest()


# -- checks ---------------------------------------------------------------------------------


def check_advisor(advisor: Advisor, observations: np.ndarray) -> None:
    """Refuses an advisor that is not jittable, does not return one action of shape (2,),
    or returns a non-finite action on ``observations`` ([n, 20], e.g. an arena's starts):
    ValueError naming the advisor and what it returned."""
    what = f"advisor {advisor.spec!r}"
    one = jax.ShapeDtypeStruct((spec.OBS_SIZE,), jnp.float32)
    try:
        out = jax.eval_shape(advisor.apply, advisor.params, one)
    except jax.errors.JAXTypeError as e:
        raise ValueError(
            f"{what} is not jittable: {_first_line(e)} (it is traced: decide with jnp.where "
            "or jax.lax.cond on the observation, not with Python if/float/int)"
        ) from None
    except Exception as e:  # anything the user's function raises while traced
        raise ValueError(
            f"{what} fails on an observation of shape (20,): {_first_line(e)}"
        ) from None
    shape = getattr(out, "shape", None)
    dtype = getattr(out, "dtype", None)
    if shape != (spec.ACTION_SIZE,) or dtype is None or not jnp.issubdtype(dtype, jnp.floating):
        got = f"{type(out).__name__} {shape} {dtype}" if shape is not None else repr(out)[:80]
        raise ValueError(
            f"{what} returned {got} for one observation of shape (20,); it must return one "
            "float action [V, ω] of shape (2,)"
        )
    batched = jax.jit(jax.vmap(advisor.apply, in_axes=(None, 0)))
    actions = np.asarray(batched(advisor.params, observations))
    bad = np.flatnonzero(~np.isfinite(actions).all(axis=-1))
    if bad.size:
        i = int(bad[0])
        raise ValueError(
            f"{what} returned the non-finite action {actions[i].tolist()} for observation "
            f"{np.round(observations[i], 3).tolist()} ({bad.size} of {len(observations)} "
            "sample observations)"
        )


def _first_line(e: BaseException) -> str:
    text = str(e).strip().splitlines()
    return f"{type(e).__name__}: {text[0][:200]}" if text else type(e).__name__
