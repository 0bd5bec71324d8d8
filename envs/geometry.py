"""Pure-JAX 2-D geometry of the arenas: boxes, the robot's circular footprint, spawning.

An arena is a set of boxes seen from above; walls are boxes too. A box is one row of a
``[n, 5]`` float array ``(cx, cy, hx, hy, angle)``: centre (m), half extents along its own
axes (m) and rotation about +z (rad, counter-clockwise). Everything here is jit- and
vmap-safe (no Python control flow on traced values) and works on any number of boxes.

Used for (paper §5.1, §5.4; docs/architecture.md, "Environment"):

* the geometric half of the collision test: the robot circle (radius r) touches a box
  iff the signed distance from its centre to the box is <= r. This catches corners that
  slip between two sonar rays, which the paper's sensor rule (min P <= T_c) cannot see;
* collision-free sampling of start poses and goals with a fixed number of candidates
  (no while loop). Fixed arenas sample from precomputed tables of free grid cells
  (``free_cells``, ``sample_spawn_cells``): one start candidate is always valid, and goal
  candidates are only rejected for being too close to the start. The procedural arena,
  whose boxes change every episode, rejection-samples 64 candidates (``sample_spawn``).

Signed distance to a box (the usual SDF): with q = |R^T (p - c)| - h,
``sdf = |max(q, 0)| + min(max(q_x, q_y), 0)``; negative inside.
"""

from __future__ import annotations

import math
from typing import Any

import jax
import jax.numpy as jnp
import numpy as np
from flax import struct

BOX_FIELDS = ("cx", "cy", "hx", "hy", "angle")


def box_sdf(point: Any, boxes: Any, xp: Any = jnp) -> Any:
    """Signed distance (m) from 2-D point(s) to each box; negative inside.

    Args:
      point: [..., 2] world x, y.
      boxes: [n, 5] rows (cx, cy, hx, hy, angle).
      xp: array module (``jax.numpy``, or ``numpy`` for host-side tables).

    Returns:
      [..., n] signed distances.
    """
    rel = point[..., None, :] - boxes[:, :2]  # [..., n, 2]
    cos, sin = xp.cos(boxes[:, 4]), xp.sin(boxes[:, 4])
    # Rotate into each box's frame: R^T rel.
    lx = cos * rel[..., 0] + sin * rel[..., 1]
    ly = -sin * rel[..., 0] + cos * rel[..., 1]
    qx, qy = xp.abs(lx) - boxes[:, 2], xp.abs(ly) - boxes[:, 3]  # [..., n]
    outside = xp.sqrt(xp.square(xp.maximum(qx, 0.0)) + xp.square(xp.maximum(qy, 0.0)))
    inside = xp.minimum(xp.maximum(qx, qy), 0.0)
    return outside + inside


def clearance(point: jax.Array, boxes: jax.Array) -> jax.Array:
    """Distance (m) from a point to the nearest box surface; negative inside a box."""
    if boxes.shape[0] == 0:
        return jnp.asarray(jnp.inf, point.dtype)
    return jnp.min(box_sdf(point, boxes))


def footprint_collides(center: jax.Array, radius: float, boxes: jax.Array) -> jax.Array:
    """True when a circle of ``radius`` at ``center`` [2] touches or overlaps any box."""
    return clearance(center, boxes) <= radius


@struct.dataclass
class Spawn:
    """A sampled episode start."""

    pose: jax.Array  # [3] x, y, heading θ (rad)
    goal: jax.Array  # [2] x, y
    valid: jax.Array  # () bool: a candidate met every rule (False: best-effort fallback)


def sample_spawn(
    key: jax.Array,
    boxes: jax.Array,
    bounds: tuple[float, float, float, float],
    *,
    radius: float,
    start_clearance: float,
    goal_clearance: float,
    min_goal_distance: float,
    n_candidates: int = 64,
) -> Spawn:
    """Samples a start pose and a goal, both collision-free, with a minimum separation.

    Rules: the robot circle at the start is at least ``start_clearance`` (free distance)
    from every box; the goal point is at least ``radius + goal_clearance`` from every box
    (the footprint fits there with room to spare); ``|goal - start| >= min_goal_distance``.
    Positions are uniform in ``bounds`` (xmin, xmax, ymin, ymax), the heading is uniform in
    [-π, π). ``n_candidates`` starts and goals are drawn at once and the first valid one is
    taken, so the cost is fixed. If no start candidate is valid, the one with the most
    clearance is used; if no goal is valid, the goal candidate with the best
    min(clearance margin, separation margin) is used; ``valid`` is then False. With the
    arenas' acceptance rates (tested) this needs more than 64 failures in a row, i.e. it
    does not happen in practice.
    """
    key_start, key_goal, key_heading = jax.random.split(key, 3)
    # Within ``radius`` of a wall the footprint overlaps it: no need to draw there.
    low = jnp.array([bounds[0] + radius, bounds[2] + radius])
    high = jnp.array([bounds[1] - radius, bounds[3] - radius])
    starts = jax.random.uniform(key_start, (n_candidates, 2), minval=low, maxval=high)
    goals = jax.random.uniform(key_goal, (n_candidates, 2), minval=low, maxval=high)
    heading = jax.random.uniform(key_heading, (), minval=-jnp.pi, maxval=jnp.pi)

    start_margin = jnp.min(box_sdf(starts, boxes), axis=-1) - radius - start_clearance
    start_ok = start_margin >= 0.0
    start_idx = jnp.where(jnp.any(start_ok), jnp.argmax(start_ok), jnp.argmax(start_margin))
    start = starts[start_idx]

    goal_margin = jnp.min(box_sdf(goals, boxes), axis=-1) - radius - goal_clearance
    sep_margin = jnp.linalg.norm(goals - start[None, :], axis=-1) - min_goal_distance
    goal_score = jnp.minimum(goal_margin, sep_margin)  # [n_candidates]
    goal_ok = goal_score >= 0.0
    goal_idx = jnp.where(jnp.any(goal_ok), jnp.argmax(goal_ok), jnp.argmax(goal_score))

    pose = jnp.concatenate([start, heading[None]])
    return Spawn(pose=pose, goal=goals[goal_idx], valid=jnp.any(start_ok) & jnp.any(goal_ok))


# ---- fixed arenas: exact sampling from precomputed free cells -------------------------


def free_cells(
    boxes: np.ndarray, bounds: tuple[float, float, float, float], required: float, cell: float
) -> np.ndarray:
    """Lower-left corners [k, 2] of the grid cells whose every point is >= ``required``
    from every box (host-side numpy, once per arena).

    The box SDF is 1-Lipschitz, so a cell is entirely valid when its centre clears
    ``required`` plus half its diagonal. Sampling a cell uniformly and a point uniformly in
    it is then exactly uniform over the valid region minus a band of at most one cell
    diagonal along its boundary.
    """
    xmin, xmax, ymin, ymax = bounds
    xs = np.arange(xmin, xmax - cell / 2, cell)
    ys = np.arange(ymin, ymax - cell / 2, cell)
    corners = np.stack(np.meshgrid(xs, ys, indexing="ij"), -1).reshape(-1, 2)
    centres = corners + cell / 2.0
    sdf = box_sdf(centres, np.asarray(boxes, np.float64), xp=np).min(axis=-1)
    return corners[sdf >= required + cell * math.sqrt(0.5)].astype(np.float32)


def goal_candidates_needed(
    n_goal_cells: int, cell: float, min_goal_distance: float, failure: float = 1e-15
) -> int:
    """Goal candidates so that P(all within ``min_goal_distance`` of the start) <= failure.

    Upper bound of the chance that one uniform goal is too close: disk area / valid area.
    """
    area = max(n_goal_cells, 1) * cell * cell
    p_close = min(math.pi * min_goal_distance**2 / area, 0.99)
    if p_close <= 0.0:
        return 1
    return max(1, math.ceil(math.log(failure) / math.log(p_close)))


def _unit_floats(bits: jax.Array) -> jax.Array:
    """uint32 random bits → floats uniform in [0, 1) (23 mantissa bits, as jax.random)."""
    one = jnp.uint32(0x3F800000)
    return jax.lax.bitcast_convert_type((bits >> 9) | one, jnp.float32) - 1.0


def sample_spawn_cells(
    key: jax.Array,
    start_cells: jax.Array,
    goal_cells: jax.Array,
    *,
    cell: float,
    min_goal_distance: float,
    n_goal_candidates: int,
) -> Spawn:
    """Start uniform over ``start_cells``, heading uniform, goal uniform over ``goal_cells``
    at least ``min_goal_distance`` from the start (first of ``n_goal_candidates``; the
    farthest one, with ``valid`` False, if none qualifies).

    All randomness comes from one draw of 32-bit words (this runs at every step under
    vmap, as the auto-reset branch). Cell indices are ``word mod cells``: the modulo bias
    is below cells / 2^32 < 1e-5.
    """
    n = n_goal_candidates
    bits = jax.random.bits(key, (4 + 3 * n,), jnp.uint32)
    unit = _unit_floats(bits)
    start = start_cells[bits[0] % start_cells.shape[0]] + cell * unit[1:3]
    heading = (2.0 * unit[3] - 1.0) * jnp.pi
    gidx = bits[4 : 4 + n] % goal_cells.shape[0]
    goals = goal_cells[gidx] + cell * unit[4 + n :].reshape(n, 2)  # [n, 2]
    sep = jnp.linalg.norm(goals - start[None, :], axis=-1)
    ok = sep >= min_goal_distance
    pick = jnp.where(jnp.any(ok), jnp.argmax(ok), jnp.argmax(sep))
    pose = jnp.concatenate([start, heading[None]])
    return Spawn(pose=pose, goal=goals[pick], valid=jnp.any(ok))


@struct.dataclass
class SpawnTables:
    """Free-cell tables of a fixed arena (``free_cells``) and the goal candidate count."""

    start_cells: jax.Array  # [k, 2] corners of cells where the start footprint fits
    goal_cells: jax.Array  # [k', 2] corners of cells where a goal may lie
    cell: float = struct.field(pytree_node=False)
    min_goal_distance: float = struct.field(pytree_node=False)
    goal_candidates: int = struct.field(pytree_node=False)

    def sample(self, key: jax.Array) -> Spawn:
        return sample_spawn_cells(
            key,
            self.start_cells,
            self.goal_cells,
            cell=self.cell,
            min_goal_distance=self.min_goal_distance,
            n_goal_candidates=self.goal_candidates,
        )


def make_spawn_tables(
    boxes: np.ndarray,
    bounds: tuple[float, float, float, float],
    *,
    radius: float,
    start_clearance: float,
    goal_clearance: float,
    min_goal_distance: float,
    max_goal_candidates: int,
    cell: float = 0.02,
) -> SpawnTables:
    """Tables for ``sample_spawn_cells``; ValueError if the start or goal has no room."""
    start = free_cells(boxes, bounds, radius + start_clearance, cell)
    goal = free_cells(boxes, bounds, radius + goal_clearance, cell)
    for what, cells, clear in (("start", start, start_clearance), ("goal", goal, goal_clearance)):
        if len(cells) == 0:
            raise ValueError(
                f"no room for a {what}: no point is robot_radius + {what}_clearance = "
                f"{radius + clear} m from every box"
            )
    needed = goal_candidates_needed(len(goal), cell, min_goal_distance)
    return SpawnTables(
        start_cells=jnp.asarray(start),
        goal_cells=jnp.asarray(goal),
        cell=cell,
        min_goal_distance=min_goal_distance,
        goal_candidates=min(max_goal_candidates, needed),
    )
