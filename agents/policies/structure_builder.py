"""Building a structure from true poses with the top-down primitives: the suite's certificates.

``build_structure`` runs, on a bare ``Workcell``, a fixed order of grasps and places (and, for a prebuilt
structure, grasps that take pieces away to a free spot) on the simulator's true poses.  A structure whose
certificate builds it on several seeds is one the arm can build: that is what admits it to the suite.  The
order is the structure's ``order`` or bottom-up; each place turns the hand so that its ~20 cm closing axis
points away from the pieces already standing higher than the new piece's bottom.  World frame, metres,
radians.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass, field

import numpy as np

from panda_grasp_env.model.structures import Structure, grip_headings, symmetry, wrapped
from panda_grasp_env.primitives.result import PrimitiveResult
from panda_grasp_env.primitives.top_down import grasp, place
from panda_grasp_env.sim.stacking import HAND_REACH, least_crowded
from panda_grasp_env.sim.structure_layout import StructureLayout
from panda_grasp_env.sim.workcell import Workcell
from panda_grasp_env.tasks.structure_build import AWAY_DISTANCE, PLACE_TOLERANCE, TURN_TOLERANCE


@dataclass
class BuildOutcome:
    """What a build did: every primitive's result in order, and whether every goal piece stood in place at the
    end (``misplaced``: the goal pieces that did not, by index)."""

    steps: list[PrimitiveResult] = field(default_factory=list)
    misplaced: list[int] = field(default_factory=list)
    success: bool = False


def bottom_up_order(structure: Structure) -> list[int]:
    """Piece indices by their bottom's height, then as listed; a prebuilt structure's removed pieces top-down."""
    if structure.prebuilt:
        return sorted(structure.removed, key=lambda i: -structure.pieces[i].position[2])
    heights = [p.position[2] - p.half_extents[2] for p in structure.pieces]
    return sorted(range(len(structure.pieces)), key=lambda i: (round(heights[i], 4), i))


class StructureBuilder:
    """One build of ``structure`` laid out as ``layout`` in ``cell``, whose object slots ``slots`` hold the
    structure's pieces in order (loose or standing, as the start has them)."""

    def __init__(self, cell: Workcell, structure: Structure, layout: StructureLayout, slots: Sequence[int]) -> None:
        self.cell, self.structure, self.layout = cell, structure, layout
        self.slots = [int(s) for s in slots]
        self.targets, self.target_yaws = structure.world_poses(layout.origin, layout.heading)
        self.outcome = BuildOutcome()

    def _in_the_way(self, centre: np.ndarray, height: float, exclude: int) -> np.ndarray:
        """Centres (n, 2) of the other pieces within ``HAND_REACH`` of ``centre`` whose top stands higher than
        ``height`` (metres): those the open hand may meet."""
        data = self.cell.data
        centres = [
            data.xpos[body][:2]
            for i, body in enumerate(self.slots)
            if i != exclude
            and data.xpos[body][2] + self.structure.pieces[i].half_extents[2] > height + 0.001
            and np.linalg.norm(data.xpos[body][:2] - centre[:2]) < HAND_REACH
        ]
        return np.array(centres).reshape(-1, 2)

    def _clearest(self, centre: np.ndarray, headings: list[float], height: float, exclude: int) -> float:
        """Of ``headings`` (radians), the one whose closing axis points least at the pieces in the way, within
        [-pi/2, pi/2) (the hand is symmetric under a half turn)."""
        return least_crowded(centre, headings, self._in_the_way(centre, height, exclude))

    def _grasp(self, index: int) -> bool:
        body, piece = self.slots[index], self.structure.pieces[index]
        position = self.cell.data.xpos[body].copy()
        yaw = float(np.arctan2(self.cell.data.xmat[body][3], self.cell.data.xmat[body][0]))
        heading = self._clearest(position, grip_headings(piece.kind, yaw), position[2] - piece.half_extents[2], index)
        result = grasp(self.cell, *position, heading)
        self.outcome.steps.append(result)
        return result.success

    def _held_turn(self, index: int) -> float:
        """The held piece's heading relative to the hand's closing axis, radians."""
        xmat = self.cell.data.xmat[self.slots[index]]
        return float(np.arctan2(xmat[3], xmat[0])) - self.cell.robot.ee_yaw

    def place_piece(self, index: int) -> bool:
        """Grasp piece ``index`` where it lies and place it at its target."""
        if not self._grasp(index):
            return False
        piece = self.structure.pieces[index]
        target, target_yaw = self.targets[index], float(self.target_yaws[index])
        bottom = target[2] - piece.half_extents[2]
        hand = target_yaw - self._held_turn(index)
        # A cube's symmetry lets the hand turn a quarter: keep the closing axis off the pieces in the way.
        candidates = [hand, hand + symmetry(piece.kind)] if piece.kind == "cube" else [hand]
        heading = self._clearest(target, candidates, bottom, index)
        result = place(self.cell, target[0], target[1], bottom, heading)
        self.outcome.steps.append(result)
        return result.success

    def take_away(self, index: int, drop: np.ndarray) -> bool:
        """Grasp piece ``index`` off the structure and put it down at table point ``drop`` (x, y)."""
        if not self._grasp(index):
            return False
        result = place(self.cell, drop[0], drop[1], 0.0, self.cell.robot.ee_yaw)
        self.outcome.steps.append(result)
        return result.success

    def in_place(self) -> list[int]:
        """The goal pieces (by index) not within ``PLACE_TOLERANCE`` and ``TURN_TOLERANCE`` of their targets."""
        data, off = self.cell.data, []
        for index, piece in enumerate(self.structure.pieces):
            if index in self.structure.removed:
                continue
            body = self.slots[index]
            yaw = float(np.arctan2(data.xmat[body][3], data.xmat[body][0]))
            turn = abs(wrapped(yaw - self.target_yaws[index], symmetry(piece.kind)))
            tilt = np.arccos(np.clip(data.xmat[body][8], -1.0, 1.0))
            shift = np.linalg.norm(data.xpos[body] - self.targets[index])
            if shift > PLACE_TOLERANCE or turn > TURN_TOLERANCE or tilt > TURN_TOLERANCE:
                off.append(index)
        return off

    def removed_clear(self) -> bool:
        """Every removed piece lies ``AWAY_DISTANCE`` or more from every goal piece's target."""
        goal = [self.targets[i][:2] for i in range(len(self.slots)) if i not in self.structure.removed]
        return all(
            min(np.linalg.norm(self.cell.data.xpos[self.slots[i]][:2] - g) for g in goal) >= AWAY_DISTANCE
            for i in self.structure.removed
        )


def build_structure(
    cell: Workcell,
    structure: Structure,
    layout: StructureLayout,
    slots: Sequence[int],
    order: Sequence[int] | None = None,
    drops: np.ndarray | None = None,
) -> BuildOutcome:
    """Build ``structure`` (see ``StructureBuilder``) in ``order`` (default: its own, or ``bottom_up_order``): place each
    piece, or for a prebuilt structure take each removed piece to the next of ``drops`` (table points (n, 2);
    default: the layout's loose places).  Stops at the first primitive that fails; then waits 2 s and checks
    every goal piece in place (and every removed one away)."""
    builder = StructureBuilder(cell, structure, layout, slots)
    order = list(order or structure.order or bottom_up_order(structure))
    drops = layout.loose_positions[:, :2] if drops is None else drops
    for step, index in enumerate(order):
        done = builder.take_away(index, drops[step]) if structure.prebuilt else builder.place_piece(index)
        if not done:
            break
    cell.wait(2.0)
    builder.outcome.misplaced = builder.in_place()
    builder.outcome.success = (
        len(builder.outcome.steps) == (2 * len(order)) and not builder.outcome.misplaced and builder.removed_clear()
    )
    return builder.outcome
