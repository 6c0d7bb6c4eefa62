"""Block structures as data: which pieces stand where, in the structure's own frame.

A :class:`Structure` is a list of :class:`Piece` s (a block kind, the centre's position and a heading) in a
local frame whose origin lies on the table top (z up, metres, radians); an episode places it at a seeded
position and heading in the workspace (:meth:`Structure.world_poses`).  The same type serves the named
suite (``model.structure_suite``), tasks and users' own structures (``Structure.of`` takes a ``Structure``
or its plain mapping, as ``gym.make`` and ``evaluate.py --task-options`` give it;
``structure_suite.as_structure`` a suite name too).

Beyond the target pieces a structure may say how an episode starts and what a build must avoid:

* ``prebuilt``: the structure stands complete at the start and the goal is to take ``removed`` pieces away,
  leaving the rest in place (careful removal);
* ``scaffold``: temporary pieces, lying loose at the start, that a build may stand where they are given
  (propping a piece until what holds it is on) and must take away again: the goal does not hold them;
* ``unstable``: partial builds (sets of piece indices) that cannot stand on their own: why the structure
  needs an order, a counterweight placed first, or a temporary block.  Each is checked in simulation.
"""

from __future__ import annotations

import functools
import math
from collections.abc import Mapping, Sequence
from dataclasses import asdict, dataclass, field, replace
from typing import Any

import numpy as np

from panda_grasp_env.model.objects import ObjectShape
from panda_grasp_env.model.robot import (
    FINGER_HALF_THICKNESS,
    FINGER_HALF_WIDTH,
    FINGER_TIP_HALF_WIDTH,
    FINGERTIP_DEPTH,
    HAND_BODY_ABOVE_SITE,
    HAND_BODY_HALF_LENGTH,
    HAND_BODY_HALF_WIDTH,
)
from panda_grasp_env.model.scene import UNIFORM_BLOCK_COLOUR, SceneConfig

#: Half extents (x, y, z) of each block kind, metres, in the piece's own frame: 5 cm cubes; planks of
#: 14 x 5 x 5 cm lying along their own x axis (the longest that keeps every part within the scene's 7 cm limit
#: on a half extent; the fingers close across the 5 cm width); and props, 8 x 5 x 5 cm, the scaffolding tier's
#: temporary blocks (``PROP_FRICTION``).
BLOCK_KINDS: dict[str, tuple[float, float, float]] = {
    "cube": (0.025, 0.025, 0.025),
    "plank": (0.07, 0.025, 0.025),
    "prop": (0.04, 0.025, 0.025),
}
#: A prop's sliding friction against everything it touches: a slider (waxed, or a plastic such as acetal on
#: wood).  A prop under a plank's end carries a fifth of its load; pushing it out at the blocks' 1.0 dragged the
#: plank round on its pillar by 15-23 mm, at 0.3 the plank stays within 4 mm of its place.  At 0.1 the pushed
#: prop glides ahead of the fingers, out of touch at most control steps.
PROP_FRICTION = 0.3
#: A structure's scene: stiff world contacts (``SceneConfig.stiff_contacts``).  On MuJoCo's soft default
#: contacts a stack loaded off its centre leans as its contacts sink unevenly and creeps: the four-cube stair
#: at 80 % of its greatest overhang fell at some headings, the cantilever slid 8.7 mm across the table in
#: 10 s.  Stiff, every named structure settles by 0.2 mm and moves less than 0.3 mm in 5 s.
STRUCTURE_PHYSICS: dict[str, Any] = {"stiff_contacts": True}
#: Tiers of the named suite, in order of what a build needs beyond moving blocks.
TIERS = ("towers", "layouts", "spans", "balance", "scaffolding", "removal")
#: Two pieces may overlap by this much (metres) along every axis before they count as interpenetrating.
OVERLAP_TOLERANCE = 1e-3
#: Largest extent of a structure from its origin on the table, metres: what fits the spawn region
#: (``sim.workcell.SPAWN_REGION``, 0.30 x 0.44 m) at any heading.
MAX_RADIUS = 0.15
#: Tallest piece centre a structure may ask for, metres (eight cubes: the tower tasks' tallest).
MAX_HEIGHT = 0.40


@dataclass(frozen=True)
class Piece:
    """One block of a structure: its ``kind`` (a key of ``BLOCK_KINDS``), its centre in the structure's frame
    (metres; z is the height above the table) and its heading ``yaw`` about z (radians)."""

    kind: str
    position: tuple[float, float, float]
    yaw: float = 0.0

    def __post_init__(self) -> None:
        if self.kind not in BLOCK_KINDS:
            raise ValueError(f"piece kind must be one of {list(BLOCK_KINDS)}, got {self.kind!r}")
        position = tuple(self.position) if isinstance(self.position, (tuple, list, np.ndarray)) else ()
        if len(position) != 3 or not all(_is_finite(v) for v in position):
            raise ValueError(f"piece position must be three finite numbers (metres), got {self.position!r}")
        if not _is_finite(self.yaw):
            raise ValueError(f"piece yaw must be a finite number of radians, got {self.yaw!r}")
        object.__setattr__(self, "position", tuple(float(v) for v in position))
        object.__setattr__(self, "yaw", float(self.yaw))

    @property
    def half_extents(self) -> np.ndarray:
        return np.array(BLOCK_KINDS[self.kind])

    def shape(self, rgb: tuple[float, float, float] = UNIFORM_BLOCK_COLOUR) -> ObjectShape:
        """The object-slot shape of this piece's kind (a box of ``DENSITY``: a cube weighs 0.1 kg, a plank
        0.28 kg, a prop 0.16 kg, with ``PROP_FRICTION``), coloured ``rgb``."""
        hx, hy, hz = BLOCK_KINDS[self.kind]
        if self.kind == "cube":
            return ObjectShape("cube", (hx,), rgb)
        return ObjectShape("box", (hx, hy, hz), rgb, friction=PROP_FRICTION if self.kind == "prop" else None)

    def corners(self) -> np.ndarray:
        """The footprint's four corners (4, 2) in the structure's frame, metres."""
        hx, hy, _ = self.half_extents
        c, s = math.cos(self.yaw), math.sin(self.yaw)
        local = np.array([[hx, hy], [-hx, hy], [-hx, -hy], [hx, -hy]])
        return local @ np.array([[c, s], [-s, c]]) + self.position[:2]


@dataclass(frozen=True)
class Structure:
    """A target structure: ``pieces`` in its own frame, its suite ``tier`` (1-6, ``TIERS``; 0 for a user's),
    and how an episode starts (see the module docstring).  ``ValueError`` names what is wrong."""

    name: str
    pieces: tuple[Piece, ...]
    tier: int = 0
    description: str = ""
    prebuilt: bool = False
    removed: tuple[int, ...] = ()
    scaffold: tuple[Piece, ...] = ()
    unstable: tuple[tuple[int, ...], ...] = field(default=())
    #: The order its certificate places the pieces in (the scaffold's numbered after them; a scaffold piece's
    #: second appearance takes it away again), or takes the removed ones away; empty: bottom up, the scaffold
    #: taken away last.
    order: tuple[int, ...] = ()

    def __post_init__(self) -> None:
        if not isinstance(self.name, str) or not self.name:
            raise ValueError(f"structure name must be a non-empty string, got {self.name!r}")
        where = f"structure {self.name!r}"
        pieces = self.pieces if isinstance(self.pieces, (tuple, list)) else None
        if not pieces:
            raise ValueError(f"{where}: pieces must be a non-empty list of pieces, got {self.pieces!r}")
        object.__setattr__(self, "pieces", tuple(p if isinstance(p, Piece) else _piece(p, where) for p in pieces))
        if not (isinstance(self.tier, int) and 0 <= self.tier <= len(TIERS)):
            raise ValueError(f"{where}: tier must be an int in [0, {len(TIERS)}], got {self.tier!r}")
        n = len(self.pieces)
        object.__setattr__(self, "removed", _indices(self.removed, n, f"{where}: removed"))
        object.__setattr__(self, "unstable", tuple(_indices(s, n, f"{where}: unstable") for s in self.unstable))
        if self.removed and not self.prebuilt:
            raise ValueError(f"{where}: removed pieces need prebuilt=True (the structure stands at the start)")
        if self.prebuilt and not self.removed:
            raise ValueError(f"{where}: a prebuilt structure needs the pieces to remove (removed)")
        if len(self.removed) == n:
            raise ValueError(f"{where}: removing every piece leaves no structure")
        if not isinstance(self.scaffold, (tuple, list)):
            raise ValueError(f"{where}: scaffold must be a list of pieces, got {self.scaffold!r}")
        scaffold = tuple(p if isinstance(p, Piece) else _piece(p, where) for p in self.scaffold)
        object.__setattr__(self, "scaffold", scaffold)
        if self.prebuilt and scaffold:
            raise ValueError(f"{where}: a prebuilt structure has no scaffold")
        steps = (
            sorted(self.removed) if self.prebuilt else sorted([*range(n + len(scaffold)), *range(n, n + len(scaffold))])
        )
        valid = isinstance(self.order, (tuple, list)) and all(
            isinstance(i, (int, np.integer)) and not isinstance(i, bool) for i in self.order
        )
        if not valid or (self.order and sorted(self.order) != steps):
            raise ValueError(
                f"{where}: order must list each of {sorted(set(steps))} once (a scaffold piece's twice: placed, "
                f"then taken away), got {self.order!r}"
            )
        object.__setattr__(self, "order", tuple(int(i) for i in self.order))
        self._check_geometry(where)

    def _check_geometry(self, where: str) -> None:
        """Pieces (the scaffold's numbered after the structure's) within reach, on or above the table, apart."""
        every = self.pieces + self.scaffold
        for index, piece in enumerate(every):
            bottom = piece.position[2] - piece.half_extents[2]
            if bottom < -OVERLAP_TOLERANCE:
                raise ValueError(f"{where}: piece {index} reaches below the table (bottom at {bottom:.3f} m)")
            if piece.position[2] > MAX_HEIGHT:
                raise ValueError(f"{where}: piece {index} stands higher than {MAX_HEIGHT} m")
            reach = np.linalg.norm(piece.corners(), axis=1).max()
            if reach > MAX_RADIUS:
                raise ValueError(f"{where}: piece {index} reaches {reach:.3f} m from the origin (at most {MAX_RADIUS})")
        for i, first in enumerate(every):
            for j in range(i + 1, len(every)):
                if interpenetrate(first, every[j]):
                    raise ValueError(f"{where}: pieces {i} and {j} overlap")

    @property
    def goal(self) -> tuple[Piece, ...]:
        """The pieces that must stand at the end: all of them, or those not ``removed``."""
        return tuple(p for i, p in enumerate(self.pieces) if i not in self.removed)

    @property
    def kinds(self) -> tuple[str, ...]:
        """Every block an episode's scene holds, by kind: the pieces, then the scaffold's."""
        return tuple(p.kind for p in self.pieces + self.scaffold)

    def world_poses(
        self, origin: Sequence[float], heading: float, pieces: Sequence[Piece] | None = None
    ) -> tuple[np.ndarray, np.ndarray]:
        """Centres (n, 3) and headings (n,) in the world of ``pieces`` (default: the structure's), with the
        structure's frame at table point ``origin`` (x, y; metres) turned by ``heading`` (radians)."""
        pieces = self.pieces if pieces is None else pieces
        c, s = math.cos(heading), math.sin(heading)
        local = np.array([p.position for p in pieces])
        world = local.copy()
        world[:, 0] = origin[0] + c * local[:, 0] - s * local[:, 1]
        world[:, 1] = origin[1] + s * local[:, 0] + c * local[:, 1]
        return world, np.array([p.yaw for p in pieces]) + heading

    def to_dict(self) -> dict[str, Any]:
        """The plain mapping ``Structure.of`` reads back (JSON- and YAML-friendly)."""
        raw = asdict(self)
        for name in ("pieces", "scaffold"):
            raw[name] = [{"kind": p.kind, "position": list(p.position), "yaw": p.yaw} for p in getattr(self, name)]
        return raw

    @classmethod
    def of(cls, value: Structure | Mapping[str, Any]) -> Structure:
        """A structure from itself or its mapping (``to_dict``); ``model.structure_suite.as_structure`` also
        takes a suite name."""
        if isinstance(value, Structure):
            return value
        if not isinstance(value, Mapping):
            raise ValueError(f"a structure must be a Structure or its mapping, got {value!r}")
        unknown = sorted(set(value) - set(cls.__dataclass_fields__))
        if unknown:
            raise ValueError(f"structure: unknown field(s) {unknown}; valid: {list(cls.__dataclass_fields__)}")
        missing = sorted({"name", "pieces"} - set(value))
        if missing:
            raise ValueError(f"structure: missing field(s) {missing}")
        raw = dict(value)
        for name in ("removed", "order", "unstable"):  # JSON gives lists; anything else the checks name
            if isinstance(raw.get(name), list):
                raw[name] = tuple(tuple(v) if isinstance(v, list) else v for v in raw[name])
        return cls(**raw)


def symmetry(kind: str) -> float:
    """The turn (radians) that maps a piece of ``kind`` onto itself: a quarter for a cube, a half for a plank or
    a prop."""
    return np.pi / 2 if kind == "cube" else np.pi


def resting_pose(kind: str, rotation: np.ndarray) -> tuple[float, float]:
    """(heading, tilt) in radians of a piece of ``kind`` whose body-to-world rotation is ``rotation`` (3 x 3, or
    MuJoCo's flat ``xmat`` row).

    A piece looks the same resting on any face that has the bottom face's size (a cube on any of its six, a plank
    or a prop on any of its four long ones, upside down included), so ``tilt`` is the angle between world z and
    the nearest normal of those faces: 0 for a cube rolled onto a side.  ``heading`` is the turn about world z of
    the body axis that lies along the piece's x extent when it is upright (a plank's or a prop's length; for a
    cube, the first horizontal one), meaningful modulo ``symmetry(kind)``."""
    axes = np.asarray(rotation, dtype=float).reshape(3, 3)  # columns: the body axes in the world frame
    faces, along = _resting_axes(kind)
    best = int(np.argmax(np.abs(axes[2, list(faces)])))
    tilt = float(np.arccos(np.clip(abs(axes[2, faces[best]]), 0.0, 1.0)))
    return float(np.arctan2(axes[1, along[best]], axes[0, along[best]])), tilt


@functools.cache
def _resting_axes(kind: str) -> tuple[tuple[int, ...], tuple[int, ...]]:
    """The body axes normal to the faces a piece of ``kind`` may rest on (the bottom face's thickness above them,
    the footprint's two extents beside them), and for each the body axis that then plays the x extent's part."""
    half = np.asarray(BLOCK_KINDS[kind])
    footprint = sorted(half[:2])
    faces = tuple(
        a for a in range(3) if np.isclose(half[a], half[2]) and np.allclose(sorted(np.delete(half, a)), footprint)
    )
    along = tuple(next(b for b in range(3) if b != a and np.isclose(half[b], half[0])) for a in faces)
    return faces, along


def grip_headings(kind: str, yaw: float) -> list[float]:
    """Closing-axis headings (radians) that grip a piece of ``kind`` lying at ``yaw``: across a cube's faces,
    across a plank's or a prop's width."""
    return [yaw, yaw + np.pi / 2] if kind == "cube" else [yaw + np.pi / 2]


def wrapped(angle: float | np.ndarray, period: float) -> float | np.ndarray:
    """``angle`` (radians) modulo ``period``, into [-period/2, period/2)."""
    return (angle + period / 2) % period - period / 2


def _is_finite(value: Any) -> bool:
    return (
        isinstance(value, (int, float, np.integer, np.floating))
        and not isinstance(value, bool)
        and math.isfinite(value)
    )


def _piece(value: Any, where: str) -> Piece:
    if not isinstance(value, Mapping):
        raise ValueError(f"{where}: a piece must be a Piece or a mapping of kind, position and yaw, got {value!r}")
    unknown = sorted(set(value) - {"kind", "position", "yaw"})
    if unknown:
        raise ValueError(f"{where}: unknown piece field(s) {unknown}; valid: ['kind', 'position', 'yaw']")
    return Piece(**value)


def _indices(values: Any, n: int, what: str) -> tuple[int, ...]:
    valid = isinstance(values, (tuple, list)) and all(
        isinstance(i, (int, np.integer)) and not isinstance(i, bool) and 0 <= i < n for i in values
    )
    if not valid or len(set(values)) != len(values):
        raise ValueError(f"{what} must be distinct piece indices in [0, {n}), got {values!r}")
    return tuple(int(i) for i in values)


def interpenetrate(a: Piece, b: Piece) -> bool:
    """Whether two pieces' boxes overlap by more than ``OVERLAP_TOLERANCE``: their height intervals, and their
    footprints (``footprints_within``)."""
    za, zb = a.position[2], b.position[2]
    if abs(za - zb) >= a.half_extents[2] + b.half_extents[2] - OVERLAP_TOLERANCE:
        return False
    return footprints_within(a, b, -OVERLAP_TOLERANCE)


def footprints_within(a: Piece, b: Piece, gap: float) -> bool:
    """Whether two pieces' footprints come closer than ``gap`` (metres; negative: overlap by more than its
    size): ``rectangles_within`` of their corners."""
    return rectangles_within(a.corners(), b.corners(), gap)


def rectangles_within(a: np.ndarray, b: np.ndarray, gap: float) -> bool:
    """Whether two rectangles, by their corners in order round each (4, 2), come closer than ``gap`` (metres)
    along every edge normal of either: the separating axis test, whose gap along an axis is never more than
    their true distance."""
    for corners in (a, b):
        for k in range(2):
            edge = corners[k + 1] - corners[k]
            normal = np.array([-edge[1], edge[0]]) / np.linalg.norm(edge)
            pa, pb = a @ normal, b @ normal
            if max(pb.min() - pa.max(), pa.min() - pb.max()) >= gap:
                return False
    return True


def footprint_distance(point: Sequence[float], piece: Piece) -> float:
    """Distance (metres) from table point ``point`` (x, y) to ``piece``'s footprint: 0 inside it.  The piece's
    position and yaw are read in the point's frame."""
    c, s = math.cos(piece.yaw), math.sin(piece.yaw)
    dx, dy = point[0] - piece.position[0], point[1] - piece.position[1]
    hx, hy, _ = piece.half_extents
    along, across = abs(c * dx + s * dy) - hx, abs(-s * dx + c * dy) - hy
    return float(math.hypot(max(along, 0.0), max(across, 0.0)))


#: A slide-out's margins, metres: the hand clears the covering pieces' end and top by ``SLIDE_CLEARANCE``, the
#: fingers come down ``SLIDE_START_GAP`` beside the prop, and they press on ``SLIDE_MIN_CONTACT`` of its face or
#: more.
SLIDE_CLEARANCE, SLIDE_START_GAP, SLIDE_MIN_CONTACT = 0.004, 0.01, 0.01


@dataclass(frozen=True)
class SlideOut:
    """A push that takes a prop out sideways from under the pieces it holds up (``slide_outs``): the closed
    fingers' start (grasp site x, y, z; metres, world) and the stroke's heading (radians)."""

    start: tuple[float, float, float]
    heading: float

    def passes_over(self, piece: Piece, distance: float) -> bool:
        """Whether the hand's body, on this push's stroke of ``distance`` metres, would meet ``piece`` (a world
        pose): it stands taller than the body's bottom, under the body's sweep."""
        if piece.position[2] + piece.half_extents[2] <= self.start[2] + HAND_BODY_ABOVE_SITE:
            return False
        along = np.array([math.cos(self.heading), math.sin(self.heading)])
        across = np.array([-along[1], along[0]])
        middle = np.array(self.start[:2]) + distance / 2 * along
        half_along, half_across = distance / 2 + HAND_BODY_HALF_WIDTH, HAND_BODY_HALF_LENGTH
        signs = ((1, 1), (-1, 1), (-1, -1), (1, -1))
        sweep = np.array([middle + i * half_along * along + j * half_across * across for i, j in signs])
        return rectangles_within(piece.corners(), sweep, 0.0)


def slide_outs(prop: Piece, covers: Sequence[Piece]) -> list[SlideOut]:
    """Pushes that slide ``prop`` out from under ``covers`` (the pieces resting on it; world poses).

    The top-down hand cannot reach under a piece: its body hangs ``HAND_BODY_ABOVE_SITE`` over the grasp site,
    and no grasp or push from above fits between a prop and what it holds.  A prop that stands out past the
    covers' end can still be pushed across: the closed fingers come down beside it just past that end (their
    widest part clear of it), the body passes over the covers' top, and the fingertips press on the part of
    the prop's face that stands out.  Returns the two strokes (one each way) across the side of the prop that
    lets the fingers press on the most of its face, if that is ``SLIDE_MIN_CONTACT`` or more; none where the
    prop is too far under, or too low under its covers, for the fingers to reach.
    """
    centre = np.array(prop.position[:2])
    bottom, top = prop.position[2] - prop.half_extents[2], prop.position[2] + prop.half_extents[2]
    cover_top = max(p.position[2] + p.half_extents[2] for p in covers)
    corners = np.concatenate([p.corners() for p in covers]) - centre
    z = max(cover_top - HAND_BODY_ABOVE_SITE + SLIDE_CLEARANCE, bottom + FINGERTIP_DEPTH + 0.005)
    if z - FINGERTIP_DEPTH > top - SLIDE_MIN_CONTACT:
        return []
    found = []
    for quarter in range(4):
        angle = prop.yaw + quarter * np.pi / 2
        out = np.array([math.cos(angle), math.sin(angle)])
        half_out, half_across = prop.half_extents[quarter % 2], prop.half_extents[(quarter + 1) % 2]
        fingers = float((corners @ out).max()) + FINGER_HALF_WIDTH + SLIDE_CLEARANCE
        contact = min(half_out, fingers + FINGER_TIP_HALF_WIDTH) - max(-half_out, fingers - FINGER_TIP_HALF_WIDTH)
        if contact < SLIDE_MIN_CONTACT:
            continue
        for side in (1.0, -1.0):
            across = side * np.array([-out[1], out[0]])
            start = centre + fingers * out - (half_across + FINGER_HALF_THICKNESS + SLIDE_START_GAP) * across
            found.append((contact, SlideOut((float(start[0]), float(start[1]), float(z)), math.atan2(*across[::-1]))))
    best = max((contact for contact, _ in found), default=0.0)
    return [push for contact, push in found if contact == best]


def roomiest(pushes: Sequence[SlideOut], prop: Sequence[float], others: np.ndarray, distance: float) -> SlideOut:
    """Of ``pushes`` (non-empty), the one that leaves the prop centred at table point ``prop`` farthest from the
    ``others`` (centres (n, 2)) after a stroke of ``distance`` metres."""
    others = np.asarray(others, dtype=float).reshape(-1, 2)

    def room(push: SlideOut) -> float:
        end = np.asarray(prop[:2]) + distance * np.array([math.cos(push.heading), math.sin(push.heading)])
        return float(np.linalg.norm(others - end, axis=1).min(initial=np.inf))

    return max(pushes, key=room)


def structure_scene(base: SceneConfig, structure: Structure) -> SceneConfig:
    """``base`` with one object slot per piece of ``structure`` (its scaffold's too), no coloured blocks, and
    the structures' physics (``STRUCTURE_PHYSICS``)."""
    return replace(base, n_blocks=0, n_objects=len(structure.kinds), **STRUCTURE_PHYSICS)
