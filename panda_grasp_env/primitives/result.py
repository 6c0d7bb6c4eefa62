"""What a primitive reports, and what every primitive's motion shares: the timing and collateral bookkeeping
around it (``run_motion``) and the grasp check of both grasp motions (top-down and 6-DOF)."""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass, field
from typing import Any, TypeVar

from panda_grasp_env.primitives.parameters import PrimitiveParameters
from panda_grasp_env.sim.stepping import PhysicsError
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
    #: The parameters it ran with, as its motion received them (None if it never ran).
    parameters: PrimitiveParameters | None = None
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


Parameters = TypeVar("Parameters", bound=PrimitiveParameters)


def run_motion(
    cell: Workcell, parameters: Parameters, motion: Callable[[Workcell, Parameters], PrimitiveResult]
) -> PrimitiveResult:
    """Run a primitive's ``motion`` with its ``parameters``, watched: the collateral watch (aimed at the fixture
    under (x, y), ``Fixtures.below``: touching it is no collision) from the start to ``record_collateral``, the
    simulated time and physics steps it took, and a divergence (``PhysicsError``) turned into a
    ``"physics_error"`` result.  Every primitive, top-down or 6-DOF, runs through here."""
    start_time, start_steps = cell.sim_time, cell.physics.steps
    fixture = cell.fixtures.below(parameters.x, parameters.y)
    cell.collateral.begin(set() if fixture is None else {fixture})
    try:
        result = motion(cell, parameters)
    except PhysicsError:
        result = PrimitiveResult(parameters.primitive, False, "physics_error")
    except BaseException:
        cell.collateral.cancel()
        raise
    record_collateral(cell, result)
    result.sim_time = cell.sim_time - start_time
    result.physics_steps = cell.physics.steps - start_steps
    result.parameters = parameters
    return result
