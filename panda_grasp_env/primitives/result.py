"""What a primitive reports, and the grasp check both grasp executors (top-down and 6-DOF) share."""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Any

from panda_grasp_env.sim.workcell import Workcell

MIN_LIFT = 0.05  # a grasp succeeds only if the object rose at least this much, metres
HOLD_TIME = 0.5  # ... and stayed held this long, seconds
CLOSED_GAP = 0.002  # fingers closer than this (metres) closed on nothing
REASONS = (
    "ok",
    "missed",
    "dropped",
    "unreachable",
    "collision",
    "out_of_workspace",
    "not_holding",
    "placed_off",
    "physics_error",
    "no_ik_solution",
    "no_plan",
    "no_contact",
)
#: The per-episode counters an env reports in ``info``: a primitive's attempts (and, where given, its
#: successes) by primitive name.
COUNTED = {
    "grasp": ("grasps_attempted", "grasps_succeeded"),
    "place": ("places", "places_succeeded"),
    "push": ("pushes", None),
    "impulse": ("impulses", None),
}
COUNTERS = tuple(name for names in COUNTED.values() for name in names if name is not None)


@dataclass
class PrimitiveResult:
    """Outcome of one primitive: ``reason`` is ``"ok"`` on success, else one of ``REASONS``."""

    primitive: str
    success: bool
    reason: str
    #: Simulated seconds the primitive took.
    sim_time: float = 0.0
    #: Physics steps it took.
    physics_steps: int = 0
    #: Name of the object grasped / placed, if any.
    object: str | None = None
    params: dict[str, float] = field(default_factory=dict)
    #: Body ids of what the primitive acted on: the object grasped (or aimed at) or placed; for pushes and
    #: impulses the piles (towers, heaps) of the objects struck.  Their motion is not collateral.
    targets: set[int] = field(default_factory=set)
    #: Names of the objects, then of the fixtures, the robot or its load touched in transit (see ``collateral``).
    transit_contacts: list[str] = field(default_factory=list)
    #: Names of the objects, then of the fixtures, the robot or its load touched in the work segment.
    work_contacts: list[str] = field(default_factory=list)
    #: Names of the objects at rest that moved or tipped during transit.
    transit_disturbed: list[str] = field(default_factory=list)
    #: Names of the objects other than the targets that moved (> 1 cm) or tipped over during the primitive.
    disturbed: list[str] = field(default_factory=list)

    def count(self, counters: dict[str, int]) -> None:
        """Add this primitive to an episode's ``COUNTERS``: one attempt, and one success if it succeeded."""
        attempts, successes = COUNTED.get(self.primitive, (None, None))
        if attempts is not None:
            counters[attempts] += 1
        if successes is not None:
            counters[successes] += int(self.success)

    def info(self) -> dict[str, Any]:
        """The env's ``info`` entries of this primitive (seconds, names; collateral: see ``sim.collateral``)."""
        return {
            "primitive": self.primitive,
            "primitive_success": self.success,
            "primitive_reason": self.reason,
            "primitive_object": self.object or "",
            "primitive_sim_time": self.sim_time,
            # Collateral: counts, and the names of what was disturbed.
            "transit_contacts": len(self.transit_contacts),
            "transit_disturbed": len(self.transit_disturbed),
            "disturbed": len(self.disturbed),
            "disturbed_objects": list(self.disturbed),
            # What the robot or its load touched, objects then fixtures, by name: in transit (never wanted) and
            # in the work segment (a fixture there other than the one aimed at is a "collision").
            "transit_touched": list(self.transit_contacts),
            "work_touched": list(self.work_contacts),
        }


def closed_on(cell: Workcell) -> int | None:
    """Body id of the object between the fingers of the just-closed gripper, or ``None`` for a miss (nothing
    between them, or the fingers shut)."""
    body = cell.robot.body_between_fingers()
    return None if body is None or cell.robot.finger_gap < CLOSED_GAP else body


def lifted_and_held(cell: Workcell, body: int, start_height: float) -> bool:
    """Whether ``body`` is still between the fingers and its centre has risen at least ``MIN_LIFT`` above
    ``start_height`` (world z, metres): the test of a grasp after the lift and ``HOLD_TIME`` hold."""
    return body in cell.robot.bodies_between_fingers() and cell.data.xpos[body][2] - start_height >= MIN_LIFT


def record_collateral(cell: Workcell, result: PrimitiveResult) -> None:
    """End the workcell's collateral watch of a primitive and copy what it saw into ``result`` (names).  A work
    segment that touched a fixture the primitive was not aimed at makes it a failure with ``"collision"``."""
    record = cell.collateral.finish(result.targets)
    result.transit_contacts = sorted(map(cell.name_of, record.transit_contacts)) + sorted(record.transit_fixtures)
    result.work_contacts = sorted(map(cell.name_of, record.work_contacts)) + sorted(record.work_fixtures)
    if record.fixture_collisions and result.reason != "physics_error":
        result.success, result.reason = False, "collision"
    result.transit_disturbed = sorted(map(cell.name_of, record.transit_disturbed))
    result.disturbed = sorted(map(cell.name_of, record.disturbed))
