"""Building a structure from true poses with the top-down primitives: the suite's certificates.

``build_structure`` runs, on a bare ``Workcell``, a fixed order of grasps and places (for a prebuilt
structure, grasps that take pieces away to a free spot; for a scaffold, a push that slides it out from
under what it propped, ``structures.slide_outs``) on the simulator's true poses.  A structure whose
certificate builds it on several seeds is one the arm can build: that is what admits it to the suite.  The
order is the structure's ``order`` or bottom-up; each place turns the hand so that its ~20 cm closing axis
points away from the pieces already standing higher than the new piece's bottom.  World frame, metres,
radians.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass, field

import numpy as np

from panda_grasp_env.model.structures import (
    Piece,
    Structure,
    grip_headings,
    resting_pose,
    roomiest,
    slide_outs,
    symmetry,
    wrapped,
)
from panda_grasp_env.primitives.parameters import PrimitiveSettings
from panda_grasp_env.primitives.result import PrimitiveResult
from panda_grasp_env.primitives.top_down import grasp, in_hand_turn, place, push
from panda_grasp_env.sim.stacking import HAND_REACH, least_crowded
from panda_grasp_env.sim.structure_layout import StructureLayout
from panda_grasp_env.sim.workcell import Workcell
from panda_grasp_env.tasks.structure_build import PLACE_TOLERANCE, TURN_TOLERANCE, is_away, resting_on

#: A slide-out's stroke: the env's push length (metres), so that a planner can push it through ``env.step``.
SLIDE_DISTANCE = PrimitiveSettings(("push",)).push_distance


@dataclass
class BuildOutcome:
    """What a build did: every primitive's result in order, and whether every goal piece stood in place at the
    end (``misplaced``: the goal pieces that did not, by index)."""

    steps: list[PrimitiveResult] = field(default_factory=list)
    misplaced: list[int] = field(default_factory=list)
    success: bool = False


def bottom_up_order(structure: Structure) -> list[int]:
    """Piece indices (the scaffold's numbered after them) by their bottom's height, then as listed, and the
    scaffold's again to take it away; a prebuilt structure's removed pieces top-down."""
    if structure.prebuilt:
        return sorted(structure.removed, key=lambda i: -structure.pieces[i].position[2])
    every = structure.pieces + structure.scaffold
    heights = [p.position[2] - p.half_extents[2] for p in every]
    scaffold = range(len(structure.pieces), len(every))
    return [*sorted(range(len(every)), key=lambda i: (round(heights[i], 4), i)), *scaffold]


class StructureBuilder:
    """One build of ``structure`` laid out as ``layout`` in ``cell``, whose object slots ``slots`` hold the
    structure's pieces in order (loose or standing, as the start has them)."""

    def __init__(self, cell: Workcell, structure: Structure, layout: StructureLayout, slots: Sequence[int]) -> None:
        self.cell, self.structure, self.layout = cell, structure, layout
        self.slots = [int(s) for s in slots]
        self.every = structure.pieces + structure.scaffold
        self.targets, self.target_yaws = structure.world_poses(layout.origin, layout.heading, self.every)
        self.outcome = BuildOutcome()

    def _in_the_way(self, centre: np.ndarray, height: float, exclude: int) -> np.ndarray:
        """Centres (n, 2) of the other pieces within ``HAND_REACH`` of ``centre`` whose top stands higher than
        ``height`` (metres): those the open hand may meet."""
        data = self.cell.data
        centres = [
            data.xpos[body][:2]
            for i, body in enumerate(self.slots)
            if i != exclude
            and data.xpos[body][2] + self.every[i].half_extents[2] > height + 0.001
            and np.linalg.norm(data.xpos[body][:2] - centre[:2]) < HAND_REACH
        ]
        return np.array(centres).reshape(-1, 2)

    def _clearest(self, centre: np.ndarray, headings: list[float], height: float, exclude: int) -> float:
        """Of ``headings`` (radians), the one whose closing axis points least at the pieces in the way, within
        [-pi/2, pi/2) (the hand is symmetric under a half turn)."""
        return least_crowded(centre, headings, self._in_the_way(centre, height, exclude))

    def _grasp(self, index: int) -> bool:
        body, piece = self.slots[index], self.every[index]
        position = self.cell.data.xpos[body].copy()
        yaw = resting_pose(piece.kind, self.cell.data.xmat[body])[0]
        heading = self._clearest(position, grip_headings(piece.kind, yaw), position[2] - piece.half_extents[2], index)
        result = grasp(self.cell, *position, heading)
        self.outcome.steps.append(result)
        return result.success

    def _held_turn(self, index: int) -> float:
        """The held piece's heading relative to the hand's closing axis, radians, in whole quarter turns: the
        place takes back the rest (``in_hand_turn``)."""
        body = self.slots[index]
        turn = float(np.arctan2(self.cell.data.xmat[body][3], self.cell.data.xmat[body][0])) - self.cell.robot.ee_yaw
        return turn - in_hand_turn(self.cell, body)

    def place_piece(self, index: int) -> bool:
        """Grasp piece ``index`` (a scaffold's numbered after the structure's) where it lies and place it at its
        target."""
        if not self._grasp(index):
            return False
        piece = self.every[index]
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

    def standing(self, index: int) -> Piece:
        """Piece ``index`` where it stands now, world frame."""
        body, kind = self.slots[index], self.every[index].kind
        return Piece(kind, tuple(self.cell.data.xpos[body]), resting_pose(kind, self.cell.data.xmat[body])[0])

    def slide_out(self, index: int) -> bool:
        """Push scaffold piece ``index`` out from under the pieces resting on it (``structures.slide_outs``),
        the stroke that ends farthest from the other pieces first."""
        prop = self.standing(index)
        others = [self.standing(i) for i in range(len(self.every)) if i != index]
        pushes = slide_outs(prop, resting_on(prop, others))
        if not pushes:
            return False
        best = roomiest(pushes, prop.position, np.array([p.position[:2] for p in others]), SLIDE_DISTANCE)
        result = push(self.cell, *best.start, best.heading, SLIDE_DISTANCE)
        self.outcome.steps.append(result)
        return result.success

    def in_place(self) -> list[int]:
        """The goal pieces (by index) not within ``PLACE_TOLERANCE`` and ``TURN_TOLERANCE`` of their targets."""
        data, off = self.cell.data, []
        for index, piece in enumerate(self.structure.pieces):
            if index in self.structure.removed:
                continue
            body = self.slots[index]
            yaw, tilt = resting_pose(piece.kind, data.xmat[body])
            turn = abs(wrapped(yaw - self.target_yaws[index], symmetry(piece.kind)))
            shift = np.linalg.norm(data.xpos[body] - self.targets[index])
            if shift > PLACE_TOLERANCE or turn > TURN_TOLERANCE or tilt > TURN_TOLERANCE:
                off.append(index)
        return off

    def removed_clear(self) -> bool:
        """Every removed and scaffold piece lies away from the goal (``structure_build.is_away``)."""
        n = len(self.structure.pieces)
        goal = [
            Piece(self.every[i].kind, tuple(self.targets[i]), float(self.target_yaws[i]))
            for i in range(n)
            if i not in self.structure.removed
        ]
        spare = [*self.structure.removed, *range(n, len(self.every))]
        return all(is_away(self.cell.data.xpos[self.slots[i]][:2], goal) for i in spare)


def build_structure(
    cell: Workcell,
    structure: Structure,
    layout: StructureLayout,
    slots: Sequence[int],
    order: Sequence[int] | None = None,
    drops: np.ndarray | None = None,
) -> BuildOutcome:
    """Build ``structure`` (see ``StructureBuilder``) in ``order`` (default: its own, or ``bottom_up_order``): place each
    piece and slide each scaffold piece out again at its second appearance, or for a prebuilt structure take
    each removed piece to the next of ``drops`` (table points (n, 2); default: the layout's loose places).
    Stops at the first primitive that fails; then waits 2 s and checks every goal piece in place (and every
    removed or scaffold one away)."""
    builder = StructureBuilder(cell, structure, layout, slots)
    order = list(order or structure.order or bottom_up_order(structure))
    drops = layout.loose_positions[:, :2] if drops is None else drops
    placed: set[int] = set()
    finished = True
    for step, index in enumerate(order):
        if structure.prebuilt:
            done = builder.take_away(index, drops[step])
        elif index in placed:
            done = builder.slide_out(index)
        else:
            done = builder.place_piece(index)
            placed.add(index)
        if not done:
            finished = False
            break
    cell.wait(2.0)
    builder.outcome.misplaced = builder.in_place()
    builder.outcome.success = finished and not builder.outcome.misplaced and builder.removed_clear()
    return builder.outcome
