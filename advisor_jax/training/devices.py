"""A population over several devices: the agent axis sharded on a 1-D mesh.

The agents of a population are independent, so every device trains its share of them with
no communication inside the jitted scan: the population's state, hyperparameters and keys
carry ``NamedSharding(mesh, P("agents"))`` on their leading axis, the step index is
replicated, and ``population_functions`` jits init and chunk with those in/out shardings.

A population whose size is not a multiple of the device count is padded with *frozen*
agents: copies of agent 0 whose completed-episode count starts at N_total, so they learn
nothing (their learning rates and τ are multiplied by 0, as for any finished agent), count
no environment steps and log no episode. Nothing outside the training loop ever sees them:
``unpad`` cuts them off before checkpoints, metrics, parameters and evaluation, so a run
checkpointed on two devices resumes on one, or on three, and the other way round.

Several hosts: ``initialize_distributed`` starts JAX's own distributed runtime
(``jax.distributed.initialize``), after which ``jax.devices()`` lists every process's
devices and the mesh spans them all; each process drives its local devices, and only
process 0 writes the run directory (``is_writer``). ``to_host`` gathers a sharded tree to
numpy on every process.
"""

from __future__ import annotations

from collections.abc import Sequence
from typing import Any, NamedTuple

import jax
import jax.numpy as jnp
import numpy as np
from jax.sharding import Mesh, NamedSharding, PartitionSpec

AXIS = "agents"


class Placement(NamedTuple):
    """Where a population lives: ``mesh`` (None: one device, no sharding), the real agent
    count and the padded count (a multiple of the mesh size)."""

    mesh: Mesh | None
    n_agents: int
    n_padded: int

    @property
    def n_devices(self) -> int:
        return 1 if self.mesh is None else self.mesh.size

    def agents(self) -> NamedSharding | None:
        """Sharding of a leaf with a leading agent axis."""
        return None if self.mesh is None else NamedSharding(self.mesh, PartitionSpec(AXIS))

    def replicated(self) -> NamedSharding | None:
        return None if self.mesh is None else NamedSharding(self.mesh, PartitionSpec())


def place(n_agents: int, devices: int | None = None) -> Placement:
    """The placement of ``n_agents`` on the first ``devices`` devices (None: all of them).

    One device gives an unsharded placement (the single-device program, unchanged)."""
    available = jax.devices()
    n = len(available) if devices is None else int(devices)
    if not 1 <= n <= len(available):
        raise ValueError(
            f"--devices {devices} is out of range: this process sees {len(available)} "
            f"device(s) ({available[0].platform})"
        )
    if n == 1:
        return Placement(None, n_agents, n_agents)
    padded = -(-n_agents // n) * n  # ceil to a multiple of the device count
    return Placement(Mesh(np.array(available[:n]), (AXIS,)), n_agents, padded)


def pad(tree: Any, placement: Placement) -> Any:
    """Appends ``n_padded - n_agents`` copies of agent 0 to every leaf's leading axis."""
    extra = placement.n_padded - placement.n_agents
    if extra == 0:
        return tree

    def grow(x):
        x = jnp.asarray(x)
        return jnp.concatenate([x, jnp.repeat(x[:1], extra, axis=0)], axis=0)

    return jax.tree.map(grow, tree)


def unpad(tree: Any, placement: Placement) -> Any:
    """The real agents of a padded tree (leading axis cut to ``n_agents``). Cut host copies
    (``unpad(to_host(tree))``): cutting a sharded array on its devices all-gathers it."""
    if placement.n_padded == placement.n_agents:
        return tree
    return jax.tree.map(lambda x: x[: placement.n_agents], tree)


def freeze_padding(state: Any, placement: Placement, n_total: int) -> Any:
    """Marks the padding agents finished (N = N_total), so they stay frozen throughout."""
    if placement.n_padded == placement.n_agents:
        return state
    episodes = state.episodes.at[placement.n_agents :].set(n_total)
    return state.replace(episodes=episodes)


def shard(tree: Any, placement: Placement) -> Any:
    """Puts a (padded) tree on the mesh, agent axis split; unchanged on one device."""
    sharding = placement.agents()
    return tree if sharding is None else jax.device_put(tree, sharding)


def put(tree: Any, placement: Placement) -> Any:
    """A tree of the real agents, padded and placed on the mesh (``shard(pad(tree))``)."""
    return shard(pad(tree, placement), placement)


def init_population(init_fn: Any, keys: Any, placement: Placement, n_total: int) -> Any:
    """A population's first state as training starts it: ``init_fn`` of the real agents'
    keys padded and placed, the padding agents frozen (``freeze_padding``)."""
    return freeze_padding(init_fn(put(keys, placement)), placement, n_total)


def to_host(tree: Any) -> Any:
    """Numpy copy of a tree of (possibly sharded, possibly multi-process) arrays."""
    if jax.process_count() == 1:
        return jax.device_get(tree)
    from jax.experimental import multihost_utils

    return multihost_utils.process_allgather(tree, tiled=True)


def from_writer(tree: Any, abstract: Any) -> Any:
    """``tree`` as process 0 has it, on every process (other processes pass None): what
    process 0 read from the run directory (a checkpoint on resume)."""
    if jax.process_count() == 1:
        return tree
    from jax.experimental import multihost_utils

    if tree is None:
        tree = jax.tree.map(lambda a: np.zeros(a.shape, a.dtype), abstract)
    return multihost_utils.broadcast_one_to_all(tree)


def is_writer() -> bool:
    """Only process 0 writes the run directory."""
    return jax.process_index() == 0


def initialize_distributed(
    coordinator: str | None = None,
    num_processes: int | None = None,
    process_id: int | None = None,
    local_device_ids: Sequence[int] | None = None,
) -> None:
    """``jax.distributed.initialize`` with the given values; those left None come from the
    environment as JAX reads it (``JAX_COORDINATOR_ADDRESS``, ``JAX_NUM_PROCESSES``,
    ``JAX_PROCESS_ID``, or a SLURM / Open MPI job's variables). Call before any other JAX
    call of the process. CPU processes exchange data through gloo (GPUs use NCCL)."""
    jax.config.update("jax_cpu_collectives_implementation", "gloo")
    jax.distributed.initialize(
        coordinator_address=coordinator,
        num_processes=num_processes,
        process_id=process_id,
        local_device_ids=local_device_ids,
    )
