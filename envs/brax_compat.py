"""``jax.device_put_replicated`` for brax 0.14's trainers on jax >= 0.10 (brax issue 671).

jax 0.10 removed ``jax.device_put_replicated``; brax 0.14.2 (its newest release) still calls
it where its PPO, SAC and APG trainers place their training state on the devices
(``brax/training/agents/*/train.py``, ``brax/training/pmap.py``), so they stop with an
AttributeError. brax's main branch no longer calls it (google/brax#671). ``install`` supplies
the function only when both hold: jax lacks it and brax's installed trainers call it. When a
brax release no longer calls it, ``brax_calls_it`` is False, nothing is installed, and
``tests/envs/test_brax_compat.py`` fails to say that this module and its one caller
(``envs/brax_env.py``) can go.
"""

from __future__ import annotations

import importlib.util

import jax
import jax.numpy as jnp
import numpy as np
from jax.sharding import Mesh, NamedSharding, PartitionSpec

NAME = "device_put_replicated"
BRAX_CALLERS = (  # brax's modules that call jax.device_put_replicated (0.14.2)
    "brax.training.agents.ppo.train",
    "brax.training.agents.sac.train",
    "brax.training.agents.apg.train",
    "brax.training.pmap",
)


def device_put_replicated(x, devices):
    """What ``jax.device_put_replicated(x, devices)`` returned up to jax 0.9: every leaf of
    ``x`` copied onto each of ``devices``, stacked on a new leading axis (what ``jax.pmap``
    takes), through jax's documented replacement (``jax.device_put`` with a sharding)."""
    devices = list(devices)
    if not devices:
        raise ValueError("device_put_replicated needs at least one device")
    sharding = NamedSharding(Mesh(np.array(devices), ("replica",)), PartitionSpec("replica"))
    return jax.tree.map(
        lambda leaf: jax.device_put(jnp.stack([jnp.asarray(leaf)] * len(devices)), sharding), x
    )


def brax_calls_it() -> bool:
    """Whether the installed brax's trainers call ``jax.device_put_replicated`` (read from
    their source files, without importing them)."""
    for module in BRAX_CALLERS:
        spec = importlib.util.find_spec(module)
        if spec is not None and spec.origin and f"jax.{NAME}" in open(spec.origin).read():
            return True
    return False


def install() -> bool:
    """Supplies ``jax.device_put_replicated`` if jax lacks it and brax calls it; returns
    whether it did (``hasattr`` is False on jax >= 0.10, whose module raises a deprecation
    AttributeError for the name)."""
    if hasattr(jax, NAME) or not brax_calls_it():
        return False
    setattr(jax, NAME, device_put_replicated)
    return True
