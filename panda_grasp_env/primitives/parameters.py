"""Each primitive's parameters as one frozen, checked object, from where an agent points to the motion.

``GraspParameters``, ``PlaceParameters``, ``PushParameters``, ``ImpulseParameters`` (the top-down primitives,
VPG's parametrisation) and ``PoseGraspParameters`` (a 6-DOF grasp) check their numbers once, when they are
made: a ``ValueError`` names the primitive and the field.  The motion receives the object as it was made.
``aimed`` builds a top-down primitive's parameters from a point and heading, reading the height from the scene
when the agent does not give one.  ``to_world`` and ``to_normalised`` are the one scaling between the action
modes' [-1, 1] box and metres.

Positions are metres in the world frame, 0 = the table top; headings are radians about world z (the closing
axis for grasp and place, the direction of motion for push and impulse).
"""

from __future__ import annotations

from abc import ABC, abstractmethod
from collections.abc import Sequence
from dataclasses import astuple, dataclass, fields
from typing import ClassVar, TypeVar

import numpy as np

from panda_grasp_env.geometry import is_number
from panda_grasp_env.sim.motion import WORKSPACE
from panda_grasp_env.sim.workcell import Workcell

#: Lowest grasp-site height: the fingertips reach 15 mm below the site.
MIN_GRASP_HEIGHT = 0.02
#: Heights (metres) the z component of a normalised action spans (``primitive_z=True``, ``grasp_pose``).
PRIMITIVE_Z_RANGE = (0.0, 0.3)
#: The box (metres) that the action modes' [-1, 1] spans, per axis: x and y over ``WORKSPACE``, z over
#: ``PRIMITIVE_Z_RANGE``.
ACTION_BOX = np.array([WORKSPACE[0], WORKSPACE[1], PRIMITIVE_Z_RANGE])
#: Where a grasp closes below the top surface it aims at, metres.
GRASP_DEPTH = 0.02
#: With push faces (``SceneConfig.push_faces``), a push through nothing taller than this (metres) runs as low as
#: the fingers go (``MIN_GRASP_HEIGHT``: fingertips 5 mm above the table, the flat push faces from 7.5 mm up),
#: below the height w / (2 mu) above which a pushed object of width w and table friction mu tips over its leading
#: edge instead of sliding (7.5 mm for a 3 cm cube at the largest friction, 2, that objects take; 25 mm for a
#: 5 cm block at 1).
LOW_PUSH_MAX_HEIGHT = 0.075
#: Heights (metres) between which a push through something taller runs: half its height, so that a tower
#: topples rather than its bottom block sliding out.
PUSH_HEIGHT_RANGE = (0.03, 0.12)
#: The longest push stroke (metres) and the strongest impulse (N s).
MAX_PUSH_DISTANCE, MAX_IMPULSE = 0.3, 1.0


def to_world(normalised: np.ndarray) -> np.ndarray:
    """Metres (x, y[, z]) of an action's position in [-1, 1] per axis (``ACTION_BOX``)."""
    low, high = ACTION_BOX[: len(normalised)].T
    return low + (normalised + 1.0) / 2.0 * (high - low)


def to_normalised(point: Sequence[float] | np.ndarray) -> np.ndarray:
    """The [-1, 1] action position of world point (x, y[, z]), metres (``to_world``'s inverse)."""
    point = np.asarray(point, dtype=float)
    low, high = ACTION_BOX[: len(point)].T
    return 2 * (point - low) / (high - low) - 1


@dataclass(frozen=True)
class PrimitiveSettings:
    """The primitives an agent chooses from (in action-layout order), whether it gives heights (``with_z``),
    and the parameters it does not choose: push length (metres) and impulse (N s)."""

    primitives: tuple[str, ...]
    with_z: bool = False
    push_distance: float = 0.1  # metres (VPG)
    impulse_magnitude: float = 0.06  # N s


Parameters = TypeVar("Parameters", bound="TopDownParameters")


@dataclass(frozen=True)
class TopDownParameters(ABC):
    """A top-down primitive's parameters: grasp-site (or object) point (x, y, z) and heading ``yaw``, each a
    finite real number, stored as a float.  Each primitive's subclass says how it is aimed (``aimed``)."""

    #: The primitive's name: its results' ``primitive`` and its messages'.
    primitive: ClassVar[str]
    x: float
    y: float
    z: float
    yaw: float

    def __post_init__(self) -> None:
        for item in fields(self):
            value = getattr(self, item.name)
            if not is_number(value):
                raise ValueError(
                    f"{self.primitive}: argument {item.name!r} must be a finite real number, got {value!r}"
                )
            object.__setattr__(self, item.name, float(value))

    @classmethod
    def from_values(cls: type[Parameters], values: Sequence[float]) -> Parameters:
        """The parameters from a vector in field order (x, y, z, yaw[, distance or magnitude])."""
        names = [item.name for item in fields(cls)]
        if len(values) != len(names):
            raise ValueError(f"{cls.primitive} takes {len(names)} arguments {names}, got {len(values)}")
        return cls(*values)

    @classmethod
    @abstractmethod
    def aimed(
        cls, cell: Workcell, settings: PrimitiveSettings, x: float, y: float, yaw: float, z: float | None
    ) -> TopDownParameters:
        """The parameters at world (x, y) with heading ``yaw``; ``z=None`` picks the height (metres) from the
        scene; what the agent does not choose comes from ``settings``."""

    def values(self) -> tuple[float, ...]:
        """The parameters in field order."""
        return astuple(self)


def surface_height(cell: Workcell, x: float, y: float, exclude_body: int = -1, radius: float = 0.01) -> float:
    """Height of the highest table or object surface within ``radius`` metres of world (x, y), metres (0 = table
    top), leaving out body ``exclude_body``.

    Ray casts straight down through a 3 x 3 pattern; the robot is not seen.
    """
    return max(
        cell.surface_below(x + dx, y + dy, exclude_body)[0]
        for dx in (-radius, 0.0, radius)
        for dy in (-radius, 0.0, radius)
    )


@dataclass(frozen=True)
class GraspParameters(TopDownParameters):
    """A top-down grasp: the grasp site's target (x, y, z) and the closing axis's heading ``yaw``."""

    primitive: ClassVar[str] = "grasp"

    @classmethod
    def aimed(
        cls, cell: Workcell, settings: PrimitiveSettings, x: float, y: float, yaw: float, z: float | None
    ) -> GraspParameters:
        """Automatic height: ``GRASP_DEPTH`` below the surface at (x, y), no lower than ``MIN_GRASP_HEIGHT``."""
        z = max(surface_height(cell, x, y) - GRASP_DEPTH, MIN_GRASP_HEIGHT) if z is None else z
        return cls(x, y, z, yaw)


@dataclass(frozen=True)
class PlaceParameters(TopDownParameters):
    """A place: the held object's centre over (x, y), its bottom on a surface at height ``z``, the closing axis
    at heading ``yaw``."""

    primitive: ClassVar[str] = "place"

    @classmethod
    def aimed(
        cls, cell: Workcell, settings: PrimitiveSettings, x: float, y: float, yaw: float, z: float | None
    ) -> PlaceParameters:
        """Automatic height: the surface at (x, y), the held object left out."""
        held = cell.robot.body_between_fingers()
        z = surface_height(cell, x, y, exclude_body=-1 if held is None else held, radius=0.015) if z is None else z
        return cls(x, y, z, yaw)


@dataclass(frozen=True)
class PushParameters(TopDownParameters):
    """A push: from (x, y, z) along heading ``yaw`` for ``distance`` metres, in (0, ``MAX_PUSH_DISTANCE``]."""

    primitive: ClassVar[str] = "push"
    distance: float

    def __post_init__(self) -> None:
        super().__post_init__()
        if self.distance <= 0 or self.distance > MAX_PUSH_DISTANCE:
            raise ValueError(f"push: argument 'distance' must be in (0, 0.3] m, got {self.distance}")

    @classmethod
    def aimed(
        cls, cell: Workcell, settings: PrimitiveSettings, x: float, y: float, yaw: float, z: float | None
    ) -> PushParameters:
        """Automatic height: half the height of what lies in the stroke's path + 1 cm (within
        ``PUSH_HEIGHT_RANGE``: a tower topples), or, with push faces, as low as the fingers go through things up
        to ``LOW_PUSH_MAX_HEIGHT`` tall (they slide rather than tip).  The stroke: ``settings.push_distance``."""
        if z is None:
            ahead = np.linspace(0.0, settings.push_distance, 6)
            heights = [surface_height(cell, x + d * np.cos(yaw), y + d * np.sin(yaw)) for d in ahead]
            tallest = max(heights)
            low = cell.config.push_faces and tallest <= LOW_PUSH_MAX_HEIGHT
            z = MIN_GRASP_HEIGHT if low else float(np.clip(tallest / 2 + 0.01, *PUSH_HEIGHT_RANGE))
        return cls(x, y, z, yaw, settings.push_distance)


@dataclass(frozen=True)
class ImpulseParameters(TopDownParameters):
    """An impulse: ``magnitude`` N s, in (0, ``MAX_IMPULSE``], along heading ``yaw`` on the object nearest
    (x, y, z)."""

    primitive: ClassVar[str] = "impulse"
    magnitude: float

    def __post_init__(self) -> None:
        super().__post_init__()
        if not 0 < self.magnitude <= MAX_IMPULSE:
            raise ValueError(f"impulse: argument 'magnitude' must be in (0, 1] N s, got {self.magnitude}")

    @classmethod
    def aimed(
        cls, cell: Workcell, settings: PrimitiveSettings, x: float, y: float, yaw: float, z: float | None
    ) -> ImpulseParameters:
        """Automatic height: 2 cm below the surface at (x, y) (the top object's centre, near enough); the
        impulse: ``settings.impulse_magnitude``."""
        z = surface_height(cell, x, y) - 0.02 if z is None else z
        return cls(x, y, z, yaw, settings.impulse_magnitude)


@dataclass(frozen=True, eq=False)
class PoseGraspParameters:
    """A 6-DOF grasp: the grasp site at ``position`` (world, metres; 3) with orientation ``rotation`` (3, 3;
    x = closing axis, z = approach direction), finite; stored as read-only float arrays."""

    primitive: ClassVar[str] = "grasp"
    position: np.ndarray
    rotation: np.ndarray

    def __post_init__(self) -> None:
        for name, shape in (("position", (3,)), ("rotation", (3, 3))):
            value = np.array(getattr(self, name), dtype=float)
            if value.shape != shape or not np.isfinite(value).all():
                raise ValueError(f"{self.primitive}: argument {name!r} must be finite, of shape {shape}, got {value!r}")
            value.setflags(write=False)
            object.__setattr__(self, name, value)

    @property
    def x(self) -> float:
        return float(self.position[0])

    @property
    def y(self) -> float:
        return float(self.position[1])


#: The parameters of any primitive: what a motion receives and a ``PrimitiveResult`` keeps.
PrimitiveParameters = TopDownParameters | PoseGraspParameters
