"""Declaring a setting once: its default, its value in each preset, its range and help.

Two kinds of settings (docs/architecture.md, "Configuration"):

* **hyperparameters** (``hparam``): scalars that are pytree leaves of a ``flax.struct``
  dataclass (``HParams``, a baseline's own), so a population sweeps them in one compile
  (rejax's ``struct.field(pytree_node=True)``). Each declares its range, whether it is a
  0/1 switch or a whole episode count, and whether it ``freezes``: multiplied by 0 once
  an agent has finished (its learning rates, τ), so that it then learns nothing.
* **static settings** (``setting``): shapes, loop lengths and code paths, fields of frozen
  dataclasses (``AgentConfig``, ``TrainConfig``, ``BaselineConfig``). Changing one
  recompiles; they cannot be swept.

Both declare their value in the presets where it differs from the default (``presets``;
``PRESET_NAMES``). What follows from the declarations, here and nowhere else: a preset's
values (``preset_values``), the flat names ``--hp`` / ``--grid`` take for nested
hyperparameters (``flat_fields``, ``flat_items``, ``replace_flat``, ``from_flat``),
validation (``validate``), which hyperparameters freeze (``freeze``) and the ``--help``
table (``describe``).
"""

from __future__ import annotations

import dataclasses
import math
from collections.abc import Mapping
from typing import Any

import numpy as np
from flax import struct

PRESET_NAMES: tuple[str, ...] = ("quick", "paper", "stable", "physical")


@dataclasses.dataclass(frozen=True)
class Spec:
    """What a declaration says besides its default."""

    help: str
    presets: Mapping[str, Any]  # preset name -> its value where it differs from the default
    sweepable: bool  # a pytree leaf (``hparam``) or a static setting
    low: float = -math.inf
    high: float = math.inf
    low_closed: bool = True  # low itself allowed
    high_closed: bool = False  # high itself allowed
    switch: bool = False  # 0 or 1 only
    count: bool = False  # an episode count: a whole number
    whole: bool = False  # only whole numbers (checked)
    freezes: bool = False  # multiplied by 0 once the agent has finished
    only: tuple[str, ...] = ()  # the baseline kinds that read a static setting (empty: all)

    def interval(self) -> str:
        """The allowed values as text: ``[0, 1)``, ``0 or 1``."""
        if self.switch:
            return "0 or 1"
        lo, hi = ("[" if self.low_closed else "("), ("]" if self.high_closed else ")")
        text = f"{lo}{self.low:g}, {self.high:g}{hi}"
        return f"whole numbers in {text}" if self.whole else text

    def allows(self, values: np.ndarray) -> np.ndarray:
        """Elementwise: in the range (a positive infinity where the range is open above)."""
        ok = np.isfinite(values) | (np.isinf(values) & (self.high == math.inf) & (values > 0))
        ok &= (values >= self.low) if self.low_closed else (values > self.low)
        ok &= (values <= self.high) if self.high_closed else (values < self.high)
        if self.switch:
            ok &= (values == 0.0) | (values == 1.0)
        if self.whole:
            ok &= np.floor(values) == values
        return ok


def _check_presets(presets: Mapping[str, Any] | None) -> dict:
    unknown = set(presets or ()) - set(PRESET_NAMES)
    if unknown:
        raise ValueError(f"unknown preset {sorted(unknown)}; the presets are {PRESET_NAMES}")
    return dict(presets or {})


def hparam(default: float, help: str, *, presets: Mapping[str, float] | None = None, **spec):
    """A sweepable hyperparameter: a field of a ``flax.struct`` dataclass (a pytree leaf).
    ``spec``: ``Spec``'s range and flags (``low``, ``high``, ``low_closed``, ``high_closed``,
    ``switch``, ``count``, ``whole``, ``freezes``)."""
    meta = Spec(help=help, presets=_check_presets(presets), sweepable=True, **spec)
    return struct.field(pytree_node=True, default=default, metadata={"spec": meta})


def setting(default: Any, *, presets: Mapping[str, Any] | None = None, **spec):
    """A static setting: a field of a frozen dataclass; its help is the attribute's
    docstring. ``spec``: ``only`` (the baseline kinds that read it)."""
    meta = Spec(help="", presets=_check_presets(presets), sweepable=False, **spec)
    return dataclasses.field(default=default, metadata={"spec": meta})


def spec_of(field: dataclasses.Field) -> Spec | None:
    return field.metadata.get("spec")


def preset_values(cls: type, preset: str, changed_only: bool = False) -> dict[str, Any]:
    """``cls``'s declared fields in ``preset``: their values (``changed_only``: only where
    the preset differs from the default)."""
    if preset not in PRESET_NAMES:
        raise ValueError(f"unknown preset {preset!r}; choose one of {', '.join(PRESET_NAMES)}")
    out = {}
    for f in dataclasses.fields(cls):
        spec = spec_of(f)
        if spec is None:
            continue
        if preset in spec.presets:
            out[f.name] = spec.presets[preset]
        elif not changed_only:
            out[f.name] = f.default
    return out


# Nested hyperparameters and their flat names -------------------------------------------


def _is_struct(value: Any) -> bool:
    return dataclasses.is_dataclass(value) and not isinstance(value, type)


def flat_fields(hp: Any) -> dict[str, tuple[tuple[str, ...], Spec]]:
    """{flat name: (path of attribute names, spec)} of every declared hyperparameter of
    ``hp`` (an instance), nested structs included: ``BaselineHParams.prior.demo_episodes``
    is ``demo_episodes``. A name may appear once."""
    out: dict[str, tuple[tuple[str, ...], Spec]] = {}
    for f in dataclasses.fields(hp):
        value = getattr(hp, f.name)
        if _is_struct(value):
            inner = {k: ((f.name, *p), s) for k, (p, s) in flat_fields(value).items()}
        elif spec_of(f) is not None:
            inner = {f.name: ((f.name,), spec_of(f))}
        else:
            continue
        twice = set(out) & set(inner)
        if twice:
            raise TypeError(f"{type(hp).__name__} declares {sorted(twice)} twice")
        out.update(inner)
    return out


def _get(hp: Any, path: tuple[str, ...]) -> Any:
    for name in path:
        hp = getattr(hp, name)
    return hp


def flat_items(hp: Any) -> dict[str, Any]:
    """{flat name: value} of ``hp``'s hyperparameters, in declaration order."""
    return {name: _get(hp, path) for name, (path, _) in flat_fields(hp).items()}


def replace_flat(hp: Any, **values: Any) -> Any:
    """``hp`` with the named hyperparameters (flat names) replaced; ValueError naming an
    unknown one and the known ones."""
    fields = flat_fields(hp)
    unknown = [n for n in values if n not in fields]
    if unknown:
        raise ValueError(
            f"unknown hyperparameter {unknown[0]!r} for {type(hp).__name__}; choose from "
            f"{', '.join(fields)}"
        )

    def replace(node, prefix: tuple[str, ...]):
        changes = {}
        for f in dataclasses.fields(node):
            path = (*prefix, f.name)
            value = getattr(node, f.name)
            if _is_struct(value):
                changes[f.name] = replace(value, path)
            elif f.name in values and fields[f.name][0] == path:
                changes[f.name] = values[f.name]
        return node.replace(**changes)

    return replace(hp, ())


def from_flat(template: Any, values: Mapping[str, Any]) -> Any:
    """An instance of ``template``'s type holding ``values`` ({flat name: value}, every
    hyperparameter given)."""
    missing = set(flat_fields(template)) - set(values)
    if missing:
        raise ValueError(f"missing hyperparameters {sorted(missing)}")
    return replace_flat(template, **values)


def freeze(hp: Any, active: Any) -> Any:
    """``hp`` of an agent that learns only while ``active``: every hyperparameter declared
    ``freezes`` multiplied by it (0 once the agent has finished or diverged)."""
    frozen = {n: _get(hp, p) * active for n, (p, s) in flat_fields(hp).items() if s.freezes}
    return replace_flat(hp, **frozen)


def validate(hp: Any) -> None:
    """Every hyperparameter of ``hp`` (stacked over agents or not) within its declared
    range; ValueError naming the field, the bad value and the agent index (if stacked)."""
    for name, (path, spec) in flat_fields(hp).items():
        values = np.atleast_1d(np.asarray(_get(hp, path), dtype=np.float64))
        ok = spec.allows(values)
        if not ok.all():
            bad = int(np.flatnonzero(~ok)[0])
            where = f" (agent {bad})" if values.size > 1 else ""
            allowed = "is a switch: 0 or 1" if spec.switch else f"is outside {spec.interval()}"
            if spec.whole:
                allowed = f"is not one of the {spec.interval()}"
            raise ValueError(f"hyperparameter {name}={values[bad]:g}{where} {allowed}")


def describe(cls: type) -> list[str]:
    """One line per declared hyperparameter of ``cls``: name, default, the presets that
    differ, range, and whether it freezes (``--help``); a nested struct's too."""
    lines = []
    for f in dataclasses.fields(cls):
        spec = spec_of(f)
        nested = f.default_factory
        if spec is None and isinstance(nested, type) and dataclasses.is_dataclass(nested):
            lines += describe(nested)
            continue
        if spec is None or not spec.sweepable:
            continue
        presets = ", ".join(f"{p} {v:g}" for p, v in spec.presets.items())
        extra = f" ({presets})" if presets else ""
        freezes = "; 0 once the agent is done" if spec.freezes else ""
        lines.append(f"{f.name}: {spec.help}. {f.default:g}{extra}, in {spec.interval()}{freezes}")
    return lines
