"""Arena layouts: boundary walls and sharp-edged box obstacles (paper §5.1, §5.2, Fig. 2).

Coordinates: metres, world frame of ``advisor_jax/contract/spec.py`` (origin at the arena
centre, x right, y up). Boxes are rows ``(cx, cy, hx, hy, angle)`` as in ``geometry.py``;
the first four rows of every layout are the walls, which stand just outside ``bounds``
(the free floor). All boxes are ``BOX_HEIGHT`` tall, higher than the sensor plane.

* ``training``: 5 m × 5 m, four boxes that leave narrow (0.65–0.75 m) gaps to the walls.
  The robot is 0.44 m wide and the sensor collision rule fires at 0.1 m, so a 0.65 m gap
  is only just passable.
* ``validation``: same floor, three longer boxes with other gaps (0.65–0.9 m) (Fig. 2:
  "differs in the number of obstacles and the gap between them").
* ``physical``: 4.9 m × 3.0 m (the paper's 16 ft × 10 ft lab arena) with three 0.3–0.4 m
  boxes near the walls (the advisor reaches 36 % here; the paper's physical advisor: 32 %).
* ``procedural``: a random layout per key (``procedural_boxes``, pure JAX): 5 m × 5 m,
  between ``PROCEDURAL_MIN`` and ``PROCEDURAL_MAX`` axis-aligned or rotated boxes. The box
  array always has ``4 + PROCEDURAL_MAX`` rows; unused slots are parked (tiny, far outside
  the walls, below the floor), where no ray and no robot can reach them.

The fixed layouts (and ω_max = 3 rad/s, which the paper does not give) were tuned so that
the paper's advisor (Alg. A1, unchanged) succeeds in 40–65 % of episodes, as in the paper
(53.6 % / 50.4 %): measured 49.6 % / 54.8 % over 500 episodes (``results/advisor.md``).
Boxes in the middle of the floor trap its Braitenberg avoidance (a centre box took the
training arena from 52 % to 12 %), so obstacles stand near the walls, as in Fig. 2.
"""

from __future__ import annotations

import dataclasses

import jax
import jax.numpy as jnp
import numpy as np

BOX_HEIGHT = 0.5  # m; sensors sit at the robot's centre height (the robot radius)
WALL_THICKNESS = 0.1  # m
PARK_XY = 50.0  # m; where unused procedural slots are parked
PARK_HALF = 0.01  # m; their half extents
PROCEDURAL_MIN = 3
PROCEDURAL_MAX = 8


@dataclasses.dataclass(frozen=True)
class Layout:
    """A fixed arena: boxes [n, 5] (walls first) and the free floor's bounds."""

    name: str
    boxes: np.ndarray  # [n, 5] float32
    bounds: tuple[float, float, float, float]  # xmin, xmax, ymin, ymax

    @property
    def n_walls(self) -> int:
        return 4


def walls(bounds: tuple[float, float, float, float], thickness: float = WALL_THICKNESS):
    """Four wall boxes enclosing ``bounds``; their inner faces are the bounds."""
    xmin, xmax, ymin, ymax = bounds
    t = thickness / 2.0
    cx, cy = (xmin + xmax) / 2.0, (ymin + ymax) / 2.0
    hx, hy = (xmax - xmin) / 2.0 + thickness, (ymax - ymin) / 2.0 + thickness
    return np.array(
        [
            [xmin - t, cy, t, hy, 0.0],  # west
            [xmax + t, cy, t, hy, 0.0],  # east
            [cx, ymin - t, hx, t, 0.0],  # south
            [cx, ymax + t, hx, t, 0.0],  # north
        ],
        np.float32,
    )


def _rect(x0: float, y0: float, x1: float, y1: float) -> list[float]:
    """Axis-aligned box from two corners."""
    return [(x0 + x1) / 2, (y0 + y1) / 2, abs(x1 - x0) / 2, abs(y1 - y0) / 2, 0.0]


def _layout(name: str, bounds, obstacles: list[list[float]]) -> Layout:
    boxes = np.concatenate([walls(bounds), np.asarray(obstacles, np.float32).reshape(-1, 5)])
    return Layout(name=name, boxes=boxes.astype(np.float32), bounds=tuple(map(float, bounds)))


ARENA_5M = (-2.5, 2.5, -2.5, 2.5)
PHYSICAL_BOUNDS = (-2.45, 2.45, -1.5, 1.5)

# Obstacles as corner rectangles; the comments give the gap to the nearest wall. The
# centre is left open: a box there traps the Braitenberg advisor in most episodes.
TRAINING = _layout(
    "training",
    ARENA_5M,
    [
        _rect(-1.8, 0.3, -1.2, 1.3),  # west pillar, 0.7 m from the west wall
        _rect(-0.3, 1.3, 0.7, 1.8),  # north bar, 0.7 m from the north wall
        _rect(1.25, -0.8, 1.75, 0.4),  # east pillar, 0.75 m from the east wall
        _rect(-1.0, -1.85, 0.0, -1.35),  # south bar, 0.65 m from the south wall
    ],
)

VALIDATION = _layout(
    "validation",
    ARENA_5M,
    [
        _rect(-1.7, -0.9, -1.1, 0.5),  # west pillar, 0.8 m from the west wall
        _rect(0.2, 1.1, 1.3, 1.6),  # north bar, 0.9 m from the north wall
        _rect(0.4, -1.85, 1.0, -1.0),  # south pillar, 0.65 m from the south wall
    ],
)

PHYSICAL = _layout(
    "physical",
    PHYSICAL_BOUNDS,
    [
        _rect(-1.2, 0.5, -0.8, 0.9),  # 0.6 m from the north wall
        _rect(0.8, -0.9, 1.2, -0.5),  # 0.6 m from the south wall
        _rect(1.7, 0.6, 2.0, 1.0),  # in the north-east corner, 0.45 m from the east wall
    ],
)

FIXED_LAYOUTS: dict[str, Layout] = {lay.name: lay for lay in (TRAINING, VALIDATION, PHYSICAL)}


@dataclasses.dataclass(frozen=True)
class ArenaSpec:
    """What differs between arenas besides the boxes (paper Tables A1, A2)."""

    h_max: int  # default episode limit (Table A2: 300 simulation, 150 physical)
    obstacle_threshold: float  # advisor T_o (Appendix A: 0.5 m simulation, 0.6 m physical)
    sensor: str  # "sonar" (16-sonar ring) or "lidar" (200 beams → 16 zones, §5.2)


ARENA_SPECS: dict[str, ArenaSpec] = {
    "training": ArenaSpec(h_max=300, obstacle_threshold=0.5, sensor="sonar"),
    "validation": ArenaSpec(h_max=300, obstacle_threshold=0.5, sensor="sonar"),
    "physical": ArenaSpec(h_max=150, obstacle_threshold=0.6, sensor="lidar"),
    "procedural": ArenaSpec(h_max=300, obstacle_threshold=0.5, sensor="sonar"),
}


def procedural_boxes(key: jax.Array, bounds=ARENA_5M, max_obstacles: int = PROCEDURAL_MAX):
    """A random layout: [4 + max_obstacles, 5] boxes (walls first), pure JAX.

    Draws the obstacle count uniformly in [PROCEDURAL_MIN, max_obstacles], then per slot a
    centre uniform in the floor (kept 0.3 m off the walls), half extents uniform in
    [0.1, 0.45] m and a rotation that is 0 for half the boxes (sharp axis-aligned edges) and
    uniform in [0, π/2) for the rest. Unused slots are parked at (PARK_XY + i, PARK_XY).
    """
    key_count, key_xy, key_half, key_rot, key_tilt = jax.random.split(key, 5)
    lo = min(PROCEDURAL_MIN, max_obstacles)
    count = jax.random.randint(key_count, (), lo, max_obstacles + 1)
    xmin, xmax, ymin, ymax = bounds
    margin = 0.3
    xy = jax.random.uniform(
        key_xy,
        (max_obstacles, 2),
        minval=jnp.array([xmin + margin, ymin + margin]),
        maxval=jnp.array([xmax - margin, ymax - margin]),
    )
    half = jax.random.uniform(key_half, (max_obstacles, 2), minval=0.1, maxval=0.45)
    tilted = jax.random.bernoulli(key_tilt, 0.5, (max_obstacles,))
    angle = jnp.where(tilted, jax.random.uniform(key_rot, (max_obstacles,), maxval=jnp.pi / 2), 0.0)
    obstacles = jnp.concatenate([xy, half, angle[:, None]], axis=-1)  # [max, 5]
    slot = jnp.arange(max_obstacles, dtype=jnp.float32)
    parked = jnp.stack(
        [
            PARK_XY + slot,
            jnp.full_like(slot, PARK_XY),
            jnp.full_like(slot, PARK_HALF),
            jnp.full_like(slot, PARK_HALF),
            jnp.zeros_like(slot),
        ],
        axis=-1,
    )
    active = slot < count
    obstacles = jnp.where(active[:, None], obstacles, parked)
    return jnp.concatenate([jnp.asarray(walls(bounds)), obstacles.astype(jnp.float32)], axis=0)


def procedural_active(boxes: jax.Array) -> jax.Array:
    """[..., n] bool: which rows of procedural box arrays are walls or live obstacles."""
    return boxes[..., 0] < PARK_XY - 1.0
