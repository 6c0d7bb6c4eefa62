"""What the structure planners know of a structure build: the goal's targets, read from ``desired_goal``, and
the pieces seen, by a perceiver.

``HeightmapPieces`` reads the overhead heightmap (the camera; never ``achieved_goal``), ``OraclePieces`` the
true poses in ``achieved_goal``.  Each gives a ``Seen``: which targets hold their piece, the loose pieces, and
the pieces in the goal's way.  ``Targets`` also knows which targets hold others up and where the open fingers
have room.  World frame, metres, radians.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Any

import numpy as np
from scipy import ndimage

from panda_grasp_env.agents.policies.base import require
from panda_grasp_env.model.structures import BLOCK_KINDS, Piece, grip_headings, symmetry, wrapped
from panda_grasp_env.perception.heightmap import HeightmapGrid, heightmap_of_boxes
from panda_grasp_env.tasks.structure_build import GOAL_FIELDS, is_away, match_goal, read_rows

#: A heightmap cell this high (metres) holds something; material this much higher than the goal there is in
#: the goal's way; a target whose exposed top is seen this near its height holds its piece.
OCCUPIED, EXCESS, TOP_TOLERANCE = 0.01, 0.02, 0.012
#: How far (metres) beside a built target the heightmap may show its heights (the overhead camera sees its
#: sides) before they count as something else in the goal's way.
SMEAR = 0.015
#: A component of the heightmap smaller than this (square metres) is noise.
NOISE_AREA = 0.0008
#: How much longer (metres) a piece lying flat looks through the heightmap's blurred edges: a component is of
#: the kind whose length comes nearest its least bounding rectangle's long side, less this.
EDGE_BLUR = 0.008
#: The open fingers reach this far (metres) along the closing axis from a placed piece's centre, and are this
#: wide across it (half): a piece standing higher than the place's bottom within both is struck.
FINGER_REACH, FINGER_HALF_WIDTH = 0.045, 0.012


@dataclass(frozen=True)
class SeenPiece:
    """A piece as a perceiver sees it: ``kind``, centre (world metres) and heading (radians, modulo the kind's
    symmetry)."""

    kind: str
    position: np.ndarray
    yaw: float

    @property
    def half_height(self) -> float:
        return BLOCK_KINDS[self.kind][2]


@dataclass
class Seen:
    """What the planner knows of the scene: which targets hold their piece, the loose pieces on the table and
    the pieces in the goal's way (``excess``)."""

    filled: np.ndarray
    loose: list[SeenPiece] = field(default_factory=list)
    excess: list[SeenPiece] = field(default_factory=list)


@dataclass(frozen=True)
class Targets:
    """The goal's targets, from ``desired_goal``: kinds, centres (n, 3), headings (n,)."""

    kinds: list[str]
    centres: np.ndarray
    yaws: np.ndarray

    @classmethod
    def of(cls, desired_goal: np.ndarray) -> Targets:
        rows = np.asarray(desired_goal, dtype=float).reshape(-1, GOAL_FIELDS)
        kinds, centres, yaws = read_rows(rows[rows[:, 6] > 0.5])
        return cls(kinds, centres, yaws)

    @property
    def half_extents(self) -> np.ndarray:
        return np.array([BLOCK_KINDS[kind] for kind in self.kinds]).reshape(-1, 3)

    def pieces(self, mask: np.ndarray | None = None) -> list[Piece]:
        """The targets (those in ``mask``, default all) as pieces at their world poses."""
        chosen = range(len(self.kinds)) if mask is None else np.flatnonzero(mask)
        return [Piece(self.kinds[i], tuple(self.centres[i]), float(self.yaws[i])) for i in chosen]

    def bottom(self, index: int) -> float:
        return float(self.centres[index, 2] - self.half_extents[index, 2])

    def supports(self, index: int) -> list[int]:
        """The targets under target ``index``: their tops at its bottom, their footprints under it."""
        bottom, below = self.bottom(index), []
        for other in range(len(self.kinds)):
            top = self.centres[other, 2] + self.half_extents[other, 2]
            if other != index and abs(top - bottom) < 0.005 and self._overlap(index, other):
                below.append(other)
        return below

    def free_headings(self, index: int, standing: np.ndarray) -> list[float]:
        """Of ``grip_headings``, those whose open fingers strike none of the ``standing`` targets (a mask) that
        rise above target ``index``'s bottom."""
        bottom, free = self.bottom(index), []
        others = [
            j
            for j in np.flatnonzero(standing)
            if j != index and self.centres[j, 2] + self.half_extents[j, 2] > bottom + 0.001
        ]
        for heading in grip_headings(self.kinds[index], float(self.yaws[index])):
            axis, across = np.array([np.cos(heading), np.sin(heading)]), np.array([-np.sin(heading), np.cos(heading)])
            struck = False
            for j in others:
                offset = self.centres[j, :2] - self.centres[index, :2]
                turn = float(self.yaws[j]) - heading
                hx, hy = self.half_extents[j, :2]
                reach_along = abs(hx * np.cos(turn)) + abs(hy * np.sin(turn))
                reach_across = abs(hx * np.sin(turn)) + abs(hy * np.cos(turn))
                if (
                    abs(offset @ axis) - reach_along < FINGER_REACH
                    and abs(offset @ across) - reach_across < FINGER_HALF_WIDTH
                ):
                    struck = True
                    break
            if not struck:
                free.append(heading)
        return free

    def _overlap(self, a: int, b: int) -> bool:
        reach = np.linalg.norm(self.half_extents[a, :2]) + np.linalg.norm(self.half_extents[b, :2])
        return bool(np.linalg.norm(self.centres[a, :2] - self.centres[b, :2]) < reach - 0.01)


def _rectangle_of_cells(points: np.ndarray) -> tuple[float, float]:
    """The least-area rectangle around ``points`` (n, 2), searched by the degree: the heading of its long side
    (radians, in [0, pi)) and that side's length (metres)."""
    centred = points - points.mean(axis=0)
    best, best_area, best_length = 0.0, np.inf, 0.0
    for yaw in np.deg2rad(np.arange(0.0, 180.0, 1.0)):
        along = np.ptp(centred @ [np.cos(yaw), np.sin(yaw)])
        across = np.ptp(centred @ [-np.sin(yaw), np.cos(yaw)])
        if along >= across and along * across < best_area - 1e-9:
            best, best_area, best_length = float(yaw), along * across, float(along)
    return best, best_length


def kind_of_cells(points: np.ndarray) -> tuple[str, float]:
    """The kind of the piece lying flat whose heightmap cells are ``points`` (n, 2; world metres): the kind whose
    length comes nearest the cells' least bounding rectangle's long side, less ``EDGE_BLUR``; and its heading
    (radians, modulo the kind's symmetry)."""
    yaw, length = _rectangle_of_cells(points)
    kind = min(BLOCK_KINDS, key=lambda k: abs(2 * BLOCK_KINDS[k][0] - (length - EDGE_BLUR)))
    return kind, float(wrapped(yaw, symmetry(kind)))


class HeightmapPieces:
    """Pieces from the overhead heightmap (``obs_mode`` with ``heightmap``, wide enough for the loose pieces:
    the benchmarks' ``STRUCTURE_OPTIONS``).  Loose pieces lie flat on the table away from
    the goal: each connected region is one piece, of the kind its least bounding rectangle's length says
    (``kind_of_cells``), at that rectangle's heading.  A target holds its piece when the heights over its exposed top (not under another target) come
    within ``TOP_TOLERANCE`` of it, or when targets that do cover it whole.  What stands ``EXCESS`` above what
    the targets built explain is in the goal's way."""

    name = "camera"

    def reset(self, observation: Any, info: dict[str, Any], targets: Targets, agent: str) -> None:
        require(info, ("heightmap_grid",), agent, "make the env with a heightmap in obs_mode")
        if not isinstance(observation, dict) or "heightmap" not in observation:
            raise ValueError(f"{agent} reads the heightmap: obs_mode must hold 'heightmap'")
        self.grid = HeightmapGrid.of_layout(info["heightmap_grid"])
        self.targets = targets
        rows, cols = self.grid.shape
        self.cells = self.grid.cell_centres(*np.meshgrid(np.arange(rows), np.arange(cols), indexing="ij"))
        inner = np.maximum(targets.half_extents - [0.008, 0.008, 0.0], 0.004)
        self.footprints = [
            heightmap_of_boxes(self.grid, targets.centres[[i]], inner[[i]], targets.yaws[[i]]) > 0
            for i in range(len(targets.kinds))
        ]
        reach = int(np.ceil(SMEAR / self.grid.resolution))
        offsets = np.arange(-reach, reach + 1)
        self.smear = np.hypot(*np.meshgrid(offsets, offsets)) <= reach
        goal = heightmap_of_boxes(self.grid, targets.centres, targets.half_extents, targets.yaws)
        self.goal_area = ndimage.binary_dilation(goal > 0, iterations=max(1, int(0.03 / self.grid.resolution)))

    def __call__(self, observation: Any) -> Seen:
        heights = observation["heightmap"][..., 3]
        targets = self.targets
        filled = np.zeros(len(targets.kinds), dtype=bool)
        covered = np.zeros(heights.shape, dtype=bool)  # under the targets found filled so far
        for i in np.argsort(-targets.centres[:, 2]):  # top down: a target's top shows where no piece above hides it
            top = targets.centres[i, 2] + targets.half_extents[i, 2] - self.grid.bounds[2][0]
            exposed = self.footprints[i] & ~covered
            filled[i] = exposed.sum() < 4 or np.median(heights[exposed]) >= top - TOP_TOLERANCE
            if filled[i]:
                covered |= self.footprints[i]
        loose = self._pieces((heights > OCCUPIED) & ~self.goal_area, heights)
        # What the targets built explain, widened by ``SMEAR``: the camera sees a tower's sides as heights
        # beside it, the more the taller it stands.
        built = heightmap_of_boxes(
            self.grid, targets.centres[filled], targets.half_extents[filled], targets.yaws[filled]
        )
        explained = ndimage.grey_dilation(built, footprint=self.smear)
        excess = self._pieces((heights > explained + EXCESS) & self.goal_area, heights)
        return Seen(filled, loose, excess)

    def _pieces(self, mask: np.ndarray, heights: np.ndarray) -> list[SeenPiece]:
        labels, n = ndimage.label(mask)
        pieces = []
        for label in range(1, n + 1):
            region = labels == label
            area = region.sum() * self.grid.resolution**2
            if area < NOISE_AREA:
                continue
            points = self.cells[region]
            kind, yaw = kind_of_cells(points)
            top = float(heights[region].max()) + self.grid.bounds[2][0]
            centre = np.array([*points.mean(axis=0), top - BLOCK_KINDS[kind][2]])
            pieces.append(SeenPiece(kind, centre, yaw))
        return pieces


class OraclePieces:
    """*Oracle*: the true poses of the pieces, read from ``achieved_goal`` (a target holds its piece as the task
    judges it, ``match_goal``); a piece not on a target is loose where it lies flat on the table away from the
    goal, else in the goal's way."""

    name = "oracle"

    def reset(self, observation: Any, info: dict[str, Any], targets: Targets, agent: str) -> None:
        self.targets = targets
        self.goal = targets.pieces()

    def __call__(self, observation: Any) -> Seen:
        achieved = np.asarray(observation["achieved_goal"], dtype=float).reshape(-1, GOAL_FIELDS)
        desired = np.asarray(observation["desired_goal"], dtype=float).reshape(-1, GOAL_FIELDS)
        pairs, _ = match_goal(achieved, desired)
        filled = np.zeros(len(self.targets.kinds), dtype=bool)
        filled[[target for target, _ in pairs]] = True
        used = {piece for _, piece in pairs}
        seen = Seen(filled)
        free = [row for row, values in enumerate(achieved) if row not in used and values[6] > 0.5 and values[2] > -0.1]
        for values, kind, centre, yaw in zip(
            achieved[free], *read_rows(achieved[free])
        ):  # not on a target, on the table
            piece = SeenPiece(kind, centre.copy(), float(yaw))
            near_goal = not is_away(values[:2], self.goal)
            lying = values[2] < piece.half_height + 0.005
            (seen.excess if near_goal or not lying else seen.loose).append(piece)
        return seen
