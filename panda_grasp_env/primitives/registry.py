"""The top-down primitives by name: each one's parameters type, motion, ``info`` counters and where a pixel
action of it makes sense.  Action modes, the env's counters and ``run_primitive`` look primitives up here
instead of switching on their names."""

from __future__ import annotations

from collections.abc import Callable, Sequence
from dataclasses import dataclass
from enum import Enum
from typing import Generic, NamedTuple, TypeVar

from panda_grasp_env.primitives.parameters import (
    GraspParameters,
    ImpulseParameters,
    PlaceParameters,
    PrimitiveSettings,
    PushParameters,
    TopDownParameters,
)
from panda_grasp_env.primitives.result import PrimitiveResult, run_motion
from panda_grasp_env.primitives.top_down import grasp_motion, impulse_motion, place_motion, push_motion
from panda_grasp_env.sim.workcell import Workcell

Parameters = TypeVar("Parameters", bound=TopDownParameters)


class Target(Enum):
    """Where on the table a primitive aims (``PixelActions.action_masks``)."""

    ANYWHERE = "anywhere"  # wherever the hand can put its load
    OBJECT = "object"  # on an object
    NEAR_OBJECT = "near_object"  # on or near an object


@dataclass(frozen=True)
class Primitive(Generic[Parameters]):
    """One primitive: its parameters type (whose ``primitive`` is its name), its motion, the episode counters
    it adds to (attempts, successes or None), whether it needs an object in the hand (else an empty hand) and
    where it aims."""

    parameters: type[Parameters]
    motion: Callable[[Workcell, Parameters], PrimitiveResult]
    counters: tuple[str, str | None]
    needs_load: bool
    target: Target

    @property
    def name(self) -> str:
        return self.parameters.primitive

    def run(self, cell: Workcell, parameters: Parameters) -> PrimitiveResult:
        """Run the motion with ``parameters`` (``run_motion``: timed, collateral watched)."""
        return run_motion(cell, parameters, self.motion)


#: Every top-down primitive by name, in the order of the env's ``info`` counters.
PRIMITIVES: dict[str, Primitive] = {
    primitive.name: primitive
    for primitive in (
        Primitive(GraspParameters, grasp_motion, ("grasps_attempted", "grasps_succeeded"), False, Target.OBJECT),
        Primitive(PlaceParameters, place_motion, ("places", "places_succeeded"), True, Target.ANYWHERE),
        Primitive(PushParameters, push_motion, ("pushes", None), False, Target.NEAR_OBJECT),
        Primitive(ImpulseParameters, impulse_motion, ("impulses", None), False, Target.NEAR_OBJECT),
    )
}
_BY_PARAMETERS: dict[type[TopDownParameters], Primitive] = {p.parameters: p for p in PRIMITIVES.values()}
#: The per-episode counters an env reports in ``info``: each primitive's attempts (and, where given, successes).
COUNTERS = tuple(name for p in PRIMITIVES.values() for name in p.counters if name is not None)


def lookup(name: str) -> Primitive:
    """The primitive called ``name``; ``ValueError`` listing the valid names if there is none."""
    if name not in PRIMITIVES:
        raise ValueError(f"unknown primitive {name!r}; valid: {sorted(PRIMITIVES)}")
    return PRIMITIVES[name]


def run(cell: Workcell, parameters: TopDownParameters) -> PrimitiveResult:
    """Run the primitive whose parameters these are."""
    return _BY_PARAMETERS[type(parameters)].run(cell, parameters)


def count(result: PrimitiveResult, counters: dict[str, int]) -> None:
    """Add a primitive's result to an episode's ``COUNTERS``: one attempt, and one success if it succeeded (a
    6-DOF grasp counts as a grasp)."""
    attempts, successes = PRIMITIVES[result.primitive].counters if result.primitive in PRIMITIVES else (None, None)
    if attempts is not None:
        counters[attempts] += 1
    if successes is not None:
        counters[successes] += int(result.success)


class Aim(NamedTuple):
    """Where an agent points a primitive, in world units: (x, y) metres, heading ``yaw`` radians and the height
    ``z`` (metres), or None for the scene's (``TopDownParameters.aimed``)."""

    primitive: str
    x: float
    y: float
    yaw: float
    z: float | None = None

    def parameters(self, cell: Workcell, settings: PrimitiveSettings) -> TopDownParameters:
        """The parameters this aim gives the primitive, with heights read from ``cell`` where not given and the
        rest from ``settings``."""
        return lookup(self.primitive).parameters.aimed(cell, settings, self.x, self.y, self.yaw, self.z)


def run_primitive(cell: Workcell, name: str, values: Sequence[float]) -> PrimitiveResult:
    """Run primitive ``name`` with a parameter vector (x, y, z, yaw[, distance or magnitude])."""
    return run(cell, lookup(name).parameters.from_values(list(values)))
