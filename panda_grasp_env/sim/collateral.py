"""Collateral accounting: what a primitive touched and moved besides what it meant to.

Every primitive is split into *transit* (rising to the transit height,
crossing at it, going home) and one *work segment* (the last approach to the
work point, the work itself and the retreat straight up).  The monitor watches
every control step:

* ``transit_contacts``: objects that the robot, or the object it carries,
  touched during transit (the robot should touch nothing there), and
  ``transit_fixtures``: the fixtures (a task's bin, wall, shelf) it touched then.
  An object the robot or its load touches when a transit segment begins is
  the work's throughout that segment, not the transit's, and so is an object
  off the table resting on one of those: a neighbour lying on a grasped mesh,
  lifted with it, jostles against it all the way home (``work_contacts``; it
  moved, so it is in ``disturbed`` too).  So is what a
  load strikes once it has slipped from the fingers in transit: it falls, no
  longer carried, and what it hits is the failed grasp's doing (the grasp
  reports ``dropped``), not the transit path's;
* ``work_contacts`` / ``work_fixtures``: the same during the work segment.  A
  primitive is aimed at the fixture straight below its work point (a place on a
  shelf, a grasp in a bin); touching any other fixture in the work segment is a
  collision: the motion stops at the first touch (``new_fixture_hit``) and the
  primitive reports ``"collision"``;
* ``transit_disturbed``: objects at rest when a transit segment began that
  moved more than ``MOVE_LIMIT`` or tipped during it;
* ``disturbed``: objects other than the primitive's targets that moved more than
  ``MOVE_LIMIT`` or tipped over during the whole primitive (the agent's
  collateral, work segment included).

Metres, radians, world frame.
"""

from __future__ import annotations

from collections.abc import Iterable, Iterator
from contextlib import contextmanager
from dataclasses import dataclass, field
from typing import Protocol

import mujoco
import numpy as np

from panda_grasp_env.model.robot import PandaRobot
from panda_grasp_env.sim.fixtures import Fixtures
from panda_grasp_env.sim.parts import OwnerReference
from panda_grasp_env.sim.stepping import body_speeds

#: An object moved if its centre travelled further than this, metres.
MOVE_LIMIT = 0.01
#: An object tipped over if its own z axis turned further than this, radians.
TIP_ANGLE = np.deg2rad(30.0)
#: An object counts as at rest below this speed, m/s (a transit is not blamed for what was already moving).
REST_SPEED = 0.02


@dataclass
class Collateral:
    """What one primitive did besides its work: body ids, see the module docstring."""

    transit_contacts: set[int] = field(default_factory=set)
    transit_disturbed: set[int] = field(default_factory=set)
    #: Objects the robot or its load touched during the work segment.
    work_contacts: set[int] = field(default_factory=set)
    disturbed: set[int] = field(default_factory=set)
    #: Fixtures (by name) the robot or its load touched in transit, and in the work segment.
    transit_fixtures: set[str] = field(default_factory=set)
    work_fixtures: set[str] = field(default_factory=set)
    #: The fixtures the primitive was aimed at (straight below its work point): touching them is its work.
    aimed_fixtures: frozenset[str] = frozenset()

    @property
    def fixture_collisions(self) -> set[str]:
        """Fixtures touched in the work segment that the primitive was not aimed at."""
        return self.work_fixtures - self.aimed_fixtures


class MonitoredCell(Protocol):
    """What the monitor reads of a workcell (``Workcell`` is one; it owns the monitor, so no import of it)."""

    model: mujoco.MjModel
    data: mujoco.MjData
    robot: PandaRobot
    object_ids: np.ndarray
    fixtures: Fixtures


class CollateralMonitor:
    """Watches one workcell's contacts and object poses, segment by segment, for one primitive at a time."""

    #: The workcell that owns this part, held weakly (``sim.parts``).
    cell: OwnerReference[MonitoredCell] = OwnerReference()

    def __init__(self, cell: MonitoredCell) -> None:
        self.cell = cell
        model = cell.model
        self._is_robot = np.zeros(model.nbody, dtype=bool)
        self._is_robot[sorted(cell.robot.body_ids)] = True
        self._is_object = np.zeros(model.nbody, dtype=bool)
        self._is_object[cell.object_ids] = True
        self._is_fixture_geom = np.zeros(model.ngeom, dtype=bool)
        self._is_fixture_geom[list(cell.fixtures.names)] = True
        self._has_fixtures = bool(cell.fixtures.names)
        self.active = False
        #: Whether the last control step's contacts included a first touch, in the work segment, of a fixture
        #: the primitive was not aimed at (``Motion.move_to`` stops there).
        self.new_fixture_hit = False
        self.in_work = False
        self.record = Collateral()
        self._load = -1  # the carried object during this segment (-1: none)
        self._primitive_start: tuple[np.ndarray, np.ndarray] | None = None
        self._transit_start: tuple[np.ndarray, np.ndarray, np.ndarray] | None = None
        self._start_neighbours: dict[int, set[int]] = {}
        #: Objects the robot or its load touched when this transit segment began: the work's contacts.
        self._carried_over: set[int] = set()
        #: Whether this segment's load has left the fingers (its later contacts are the work's).
        self._load_dropped = False

    def _poses(self) -> tuple[np.ndarray, np.ndarray]:
        data, ids = self.cell.data, self.cell.object_ids
        return data.xpos[ids].copy(), data.xmat[ids].reshape(-1, 3, 3)[:, :, 2].copy()

    def _moved(self, start: tuple[np.ndarray, np.ndarray]) -> np.ndarray:
        """Per object: moved more than ``MOVE_LIMIT`` or tipped more than ``TIP_ANGLE`` since ``start``."""
        positions, z_axes = self._poses()
        shifted = np.linalg.norm(positions - start[0], axis=1) > MOVE_LIMIT
        turned = np.einsum("ij,ij->i", z_axes, start[1]) < np.cos(TIP_ANGLE)
        return shifted | turned

    def begin(self, aimed_fixtures: Iterable[str] = ()) -> None:
        """Start watching a primitive aimed at ``aimed_fixtures`` (names; see the module docstring): it starts
        in transit."""
        self.active, self.record, self._transit_start = True, Collateral(), None
        self.record.aimed_fixtures = frozenset(aimed_fixtures)
        self.new_fixture_hit = False
        self._primitive_start = self._poses()
        self._start_neighbours = self._object_neighbours()
        self._start_segment(work=False)

    def _start_segment(self, work: bool) -> None:
        self._close_transit()
        self.in_work = work
        held = self.cell.robot.body_between_fingers()
        self._load = -1 if held is None else held
        self._load_dropped = False
        if not work:
            speeds = body_speeds(self.cell.data, self.cell.object_ids)
            self._transit_start = (*self._poses(), speeds < REST_SPEED)
        self._carried_over = set() if work else self._lifted_with_hand()

    def _lifted_with_hand(self) -> set[int]:
        """Objects the robot or its load touches now, and the objects off the table that rest on those, on
        and on (a neighbour lying on a grasped mesh, lifted with it, and one lying on that neighbour)."""
        bodies = self._contact_bodies()
        on_table = {int(b) for pair in bodies[(bodies == 0).any(axis=1)] for b in pair}
        neighbours = self._object_neighbours()
        return connected(set().union(*self._touched(bodies)), neighbours, blocked=on_table | {self._load})

    def _close_transit(self) -> None:
        if self._transit_start is not None:
            positions, z_axes, resting = self._transit_start
            moved = self._moved((positions, z_axes)) & resting
            ids = self.cell.object_ids[moved]
            self.record.transit_disturbed |= {int(b) for b in ids if b != self._load}
            self._transit_start = None

    @contextmanager
    def work(self) -> Iterator[None]:
        """Mark the work segment: everything inside the ``with`` block; transit again afterwards."""
        self._start_segment(work=True)
        try:
            yield
        finally:
            self._start_segment(work=False)

    def _contact_geoms(self) -> np.ndarray:
        """Geom ids (ncon, 2) of the two sides of every current contact."""
        data = self.cell.data
        n = data.ncon
        return np.stack([data.contact.geom1[:n], data.contact.geom2[:n]], axis=1)

    def _contact_bodies(self) -> np.ndarray:
        """Body ids (ncon, 2) of the two sides of every current contact."""
        return self.cell.model.geom_bodyid[self._contact_geoms()]

    def _touched(self, bodies: np.ndarray) -> tuple[set[int], set[int]]:
        """Body ids of the objects (not the load) that the robot touches, and those the load touches, in the
        contacts between ``bodies`` (ncon, 2)."""
        objects = self._is_object[bodies] & (bodies != self._load)
        found = []
        for toucher in (self._is_robot[bodies], bodies == self._load):
            hits = np.concatenate([bodies[toucher[:, 0] & objects[:, 1], 1], bodies[toucher[:, 1] & objects[:, 0], 0]])
            found.append({int(b) for b in hits})
        return found[0], found[1]

    def on_control_step(self, cell: MonitoredCell) -> None:
        """Record the robot-object and robot-fixture contacts of the current state (the workcell's first step
        observer: called after every control step)."""
        self.new_fixture_hit = False
        if not self.active or self.cell.data.ncon == 0:
            return
        geoms = self._contact_geoms()
        bodies = self.cell.model.geom_bodyid[geoms]
        by_robot, by_load = self._touched(bodies)
        if self.in_work:
            self.record.work_contacts |= by_robot | by_load
        else:
            if by_load and not self._load_dropped:
                self._load_dropped = self._load not in self.cell.robot.bodies_between_fingers()
            work = self._carried_over | (by_load if self._load_dropped else set())
            self.record.work_contacts |= (by_robot | by_load) & work
            self.record.transit_contacts |= (by_robot | by_load) - work
        if not self._has_fixtures:  # the scene's contacts cannot touch one: skip the per-step work
            return
        robot_side = self._is_robot[bodies] | (bodies == self._load)
        fixtures = self._is_fixture_geom[geoms]
        hit = np.concatenate([geoms[robot_side[:, 0] & fixtures[:, 1], 1], geoms[robot_side[:, 1] & fixtures[:, 0], 0]])
        if hit.size:
            names = {self.cell.fixtures.names[int(g)] for g in hit}
            if self.in_work:
                self.new_fixture_hit = bool(names - self.record.aimed_fixtures - self.record.work_fixtures)
                self.record.work_fixtures |= names
            else:
                self.record.transit_fixtures |= names

    def finish(self, targets: set[int]) -> Collateral:
        """Stop watching; the record with ``disturbed`` = objects moved or tipped, other than ``targets``.

        A target that moved during transit without being touched there (a pushed tower still falling
        while the arm leaves) is not transit's doing and is left out of ``transit_disturbed``.
        """
        self._close_transit()
        if self._primitive_start is not None:
            moved = self.cell.object_ids[self._moved(self._primitive_start)]
            self.record.disturbed = {int(b) for b in moved} - targets
        self.record.transit_disturbed -= targets - self.record.transit_contacts
        self.active, self.in_work, self._primitive_start = False, False, None
        self.new_fixture_hit = False
        return self.record

    def cancel(self) -> None:
        """Stop watching without a record (the primitive raised)."""
        self.active, self.in_work, self._primitive_start, self._transit_start = False, False, None, None
        self.new_fixture_hit = False

    def pile(self, bodies: set[int]) -> set[int]:
        """``bodies`` and every object connected to them through object-object contacts at the primitive's
        start (a tower, a heap): what a push or a strike at one of them acts on."""
        return connected(bodies, self._start_neighbours)

    def _object_neighbours(self) -> dict[int, set[int]]:
        """Object-object contacts of the current state, as an adjacency map of body ids."""
        neighbours: dict[int, set[int]] = {}
        bodies = self._contact_bodies()
        for a, b in bodies[self._is_object[bodies].all(axis=1)]:
            neighbours.setdefault(int(a), set()).add(int(b))
            neighbours.setdefault(int(b), set()).add(int(a))
        return neighbours


def connected(
    bodies: set[int], neighbours: dict[int, set[int]], blocked: set[int] | frozenset[int] = frozenset()
) -> set[int]:
    """``bodies`` and every body reachable from them through ``neighbours`` (an adjacency map) without
    passing through a ``blocked`` one."""
    group, frontier = set(bodies), list(bodies)
    while frontier:
        for other in neighbours.get(frontier.pop(), ()):
            if other not in group and other not in blocked:
                group.add(other)
                frontier.append(other)
    return group
