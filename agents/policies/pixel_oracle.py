"""An oracle that builds a structure through the ``pixel`` actions a heightmap Q-network takes, from the
simulator's true poses (``PandaStructure-v0`` with ``obs_mode='heightmap'``, ``action_mode='pixel'``).

For each target, from the lowest up, it takes a loose piece of the target's kind, grasps it at the cell nearest
its centre and places it at the cell nearest the target.  The place's heading is the grip that turns the piece
onto the target's heading with the fingers across the direction to the nearest piece built beside it; the
grasp's heading is the one that ends there.  ``stride`` rounds both cells to every ``stride``-th cell: 2 is
the refined network's grid (8 mm at 4 mm cells), 4 the plain network's.

It is the ceiling of what a chooser of pixel actions can build (``benchmarks/pixel_place_ceiling.py``) and the
goal-conditioned builder's teacher (``agents/learning/goal_building.py``).  World frame, metres, radians.
"""

from __future__ import annotations

from typing import Any

import numpy as np

from panda_grasp_env.model.structures import grip_headings, symmetry, wrapped
from panda_grasp_env.perception.heightmap import HeightmapGrid
from panda_grasp_env.tasks.structure_build import GOAL_FIELDS, read_rows


def pixel_action(
    shape: tuple[int, ...], grid: HeightmapGrid, primitive: int, xy: np.ndarray, yaw: float, stride: int
) -> int:
    """The pixel action of ``primitive`` at the cell nearest world point ``xy`` (on every ``stride``-th cell) and
    the rotation nearest heading ``yaw`` (radians).  (The network's coarse grid lies in each rotation's frame;
    every ``stride``-th cell of the world grid has the same spacing.)"""
    _, rotations, rows, cols = shape
    row, col = np.round(grid.cell_position(np.asarray(xy)) / stride) * stride
    row, col = int(np.clip(row, 0, rows - 1)), int(np.clip(col, 0, cols - 1))
    rotation = int(round(wrapped(yaw, 2 * np.pi) / (2 * np.pi / rotations))) % rotations
    return int(np.ravel_multi_index((primitive, rotation, row, col), shape))


def built_beside(targets: np.ndarray, index: int, built: list[int]) -> list[int]:
    """The built targets at target ``index``'s level (centres within 1 cm in height, world metres)."""
    return [j for j in built if abs(targets[j, 2] - targets[index, 2]) < 0.01]


def clearest_heading(kind: str, targets: np.ndarray, yaws: np.ndarray, index: int, built: list[int]) -> float:
    """The closing-axis heading (radians) that grips target ``index``'s piece as it stands there and points the
    fingers away from the built targets beside it at its level: the one most across the direction to the
    nearest of them (fingers opened along a row would strike the row's last piece)."""
    headings = grip_headings(kind, float(yaws[index]))
    beside = built_beside(targets, index, built)
    if not beside:
        return headings[0]
    nearest = min(beside, key=lambda j: np.linalg.norm(targets[j, :2] - targets[index, :2]))
    direction = np.arctan2(*(targets[nearest, 1::-1] - targets[index, 1::-1]))
    return max(headings, key=lambda h: abs(np.sin(h - direction)))


class PixelPlaceOracle:
    """Plays one episode at a time: ``start`` it on the reset's goal vectors and action layout, then ask
    ``next_action`` with the achieved goal before each step.  It follows its plan whatever happens (a failed
    grasp is followed by its place), and answers None once every target has had its place.

    ``repeat_turn`` is the turn (radians) after which its last action is the same action again: a grasp of a
    cube works across either pair of faces (a quarter turn), a plank's only across its width (a half turn, the
    fingers' own symmetry); so does a place, except that a cube placed beside a built piece must keep its
    fingers off it (a half turn)."""

    def __init__(self, stride: int = 1) -> None:
        if not (isinstance(stride, int) and stride >= 1):
            raise ValueError(f"stride must be a positive int (cells between allowed aims), got {stride!r}")
        self.stride = stride
        self._plan: list[int] = []
        self._step = 0
        self.repeat_turn = np.pi

    def start(self, desired_goal: np.ndarray, action_layout: dict[str, Any], n_targets: int) -> None:
        """A new episode: its goal vector (``goal_rows`` per slot), ``info["action_layout"]`` and its target count."""
        self._shape = tuple(action_layout["shape"])
        self._grid = HeightmapGrid.of_layout(action_layout)
        self._primitives = list(action_layout["primitives"])
        rows = np.asarray(desired_goal, dtype=float).reshape(-1, GOAL_FIELDS)[:n_targets]
        self._kinds, self._targets, self._target_yaws = read_rows(rows)
        self._plan = [int(i) for i in np.argsort(self._targets[:, 2], kind="stable")]
        self._step = 0
        self._used: set[int] = set()
        self._built: list[int] = []
        self._place: tuple[np.ndarray, float] | None = None

    def next_action(self, achieved_goal: np.ndarray) -> int | None:
        """The pixel action for the next step, given the pieces' goal vector now; None when the plan is done."""
        if self._place is not None:
            xy, yaw, self.repeat_turn = self._place
            self._place = None
            return self._action("place", xy, yaw)
        if self._step >= len(self._plan):
            return None
        index = self._plan[self._step]
        self._step += 1
        rows = np.asarray(achieved_goal, dtype=float).reshape(-1, GOAL_FIELDS)
        kinds, centres, yaws = read_rows(rows[rows[:, 6] > 0.5])
        free = [s for s, k in enumerate(kinds) if k == self._kinds[index] and s not in self._used]
        if not free:
            return None
        slot = free[0]
        self._used.add(slot)
        kind = self._kinds[index]
        place = clearest_heading(kind, self._targets, self._target_yaws, index, self._built)
        place_repeats = np.pi if built_beside(self._targets, index, self._built) else symmetry(kind)
        self._built.append(index)
        turn = wrapped(self._target_yaws[index] - yaws[slot], 2 * np.pi / symmetry(kind))
        self._place = (self._targets[index, :2], place, place_repeats)
        self.repeat_turn = symmetry(kind)
        return self._action("grasp", centres[slot, :2], place - turn)

    def _action(self, primitive: str, xy: np.ndarray, yaw: float) -> int:
        return pixel_action(self._shape, self._grid, self._primitives.index(primitive), xy, yaw, self.stride)
