"""Tower geometry on true block poses: is a tower standing, how much of it, how broken.

World frame, metres, radians.  Used by the tasks (success, progress) and by
the oracle agents.
"""

from __future__ import annotations

import numpy as np

from panda_grasp_env.model.structures import wrapped


def wrap_quarter_turn(angle: np.ndarray | float) -> np.ndarray | float:
    """Angle modulo a cube's 90 degree symmetry, into [-pi/4, pi/4)."""
    return (np.asarray(angle) + np.pi / 4) % (np.pi / 2) - np.pi / 4


def stack_height(
    positions: np.ndarray, base: int, block_size: float, tolerance: float | None = None, order: list[int] | None = None
) -> int:
    """Number of blocks in the column standing on block ``base`` (see ``stack_column``)."""
    return len(stack_column(positions, base, block_size, tolerance, order))


def stack_column(
    positions: np.ndarray, base: int, block_size: float, tolerance: float | None = None, order: list[int] | None = None
) -> list[int]:
    """Indices of the blocks in the column standing on block ``base``, bottom up (empty if the base is off the table).

    Level k (k = 1, 2, ...) is a block whose centre is within ``tolerance``
    (default a fifth of the block size) of the base's in x, y and one block size
    (+- 10 %) above the block of level k - 1.  With ``order`` (block indices
    from the base up) only that order counts.
    """
    tolerance = block_size / 5 if tolerance is None else tolerance
    base_position = positions[base]
    if abs(base_position[2] - block_size / 2) > block_size / 10:
        return []
    centred = np.linalg.norm(positions[:, :2] - base_position[:2], axis=1) <= tolerance
    column = [base]
    while True:
        expected = positions[column[-1], 2] + block_size
        candidates = [
            i for i in range(len(positions)) if centred[i] and abs(positions[i, 2] - expected) <= block_size / 10
        ]
        if order is not None:
            candidates = [i for i in candidates if len(column) < len(order) and i == order[len(column)]]
        if not candidates:
            return column
        column.append(candidates[0])


def tower_is_built(positions: np.ndarray, base: int, block_size: float, tolerance: float | None = None) -> bool:
    """All blocks stacked on ``base``: centred within ``tolerance``, consecutive heights."""
    return stack_height(positions, base, block_size, tolerance) == len(positions)


def tower_footprint_centre(positions: np.ndarray) -> np.ndarray:
    """(x, y) of the lowest block: the centre of a standing tower's footprint, metres."""
    return positions[int(np.argmin(positions[:, 2])), :2].copy()


def blocks_displaced(positions: np.ndarray, footprint_centre: np.ndarray, block_size: float) -> int:
    """Number of blocks whose centre is at least one block size (horizontally) from the footprint centre."""
    offsets = np.linalg.norm(positions[:, :2] - footprint_centre, axis=1)
    return int(np.sum(offsets >= block_size))


def crowding(centre: np.ndarray, heading: float, obstacles: np.ndarray, power: int = 1) -> float:
    """How much a closing axis at ``heading`` (radians) through ``centre`` (x, y, metres) points at ``obstacles``
    (centres, (n, 2)): each weighs the cosine of its bearing off the axis over its distance to ``power``."""
    offsets = np.asarray(obstacles, dtype=float).reshape(-1, 2) - centre[:2]
    distances = np.maximum(np.linalg.norm(offsets, axis=1), 1e-6)
    along = np.abs(offsets @ [np.cos(heading), np.sin(heading)]) / distances
    return float(np.sum(along / distances**power))


#: Pieces farther than this (metres) from a grasp or place are out of the open hand's way (it reaches ~11 cm along
#: its closing axis); nearer ones weigh by the inverse square of their distance (``least_crowded``).
HAND_REACH = 0.15


def least_crowded(centre: np.ndarray, headings: list[float], obstacles: np.ndarray) -> float:
    """Of ``headings`` (radians), the one whose closing axis points least at ``obstacles`` (centres (n, 2)),
    weighed by the inverse square of their distance (``crowding``), within [-pi/2, pi/2) (the hand is
    symmetric under a half turn)."""
    best = min(headings, key=lambda heading: crowding(centre, heading, obstacles, power=2))
    return float(wrapped(best, np.pi))


def clearest_grasp_heading(positions: np.ndarray, index: int, yaw: float) -> float:
    """Of a cube's two grasp headings (``yaw``, ``yaw`` + 90 deg), the one pointing least at the other blocks
    (``crowding``).

    The open hand is ~20 cm wide along its closing axis; aiming it at a nearby
    tower knocks the tower over.
    """
    others = np.delete(positions[:, :2], index, axis=0)
    return min((yaw, yaw + np.pi / 2), key=lambda heading: crowding(positions[index], heading, others))
