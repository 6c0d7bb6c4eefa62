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

import math
from collections.abc import Mapping, Sequence
from dataclasses import asdict, dataclass, field, replace
from typing import Any

import numpy as np

from panda_grasp_env.model.objects import ObjectShape
from panda_grasp_env.model.scene import UNIFORM_BLOCK_COLOUR, SceneConfig

#: Half extents (x, y, z) of each block kind, metres, in the piece's own frame: 5 cm cubes, and planks of
#: 14 x 5 x 5 cm lying along their own x axis (the longest that keeps every part within the scene's 7 cm
#: limit on a half extent; the fingers close across the 5 cm width).
BLOCK_KINDS: dict[str, tuple[float, float, float]] = {
    "cube": (0.025, 0.025, 0.025),
    "plank": (0.07, 0.025, 0.025),
}
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
        0.28 kg), coloured ``rgb``."""
        hx, hy, hz = BLOCK_KINDS[self.kind]
        return ObjectShape("cube", (hx,), rgb) if self.kind == "cube" else ObjectShape("box", (hx, hy, hz), rgb)

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
    #: The order its certificate places the pieces in (the scaffold's numbered after them), or takes the
    #: removed ones away; empty: bottom up.
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
        order = _indices(self.order, n + len(scaffold), f"{where}: order")
        steps = sorted(self.removed) if self.prebuilt else list(range(n + len(scaffold)))
        if order and sorted(order) != steps:
            raise ValueError(f"{where}: order must list each of {steps} once, got {list(order)}")
        object.__setattr__(self, "order", order)
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
                if _interpenetrate(first, every[j]):
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
    """The turn (radians) that maps a piece of ``kind`` onto itself: a quarter for a cube, a half for a plank."""
    return np.pi / 2 if kind == "cube" else np.pi


def grip_headings(kind: str, yaw: float) -> list[float]:
    """Closing-axis headings (radians) that grip a piece of ``kind`` lying at ``yaw``: across a cube's faces,
    across a plank's width."""
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


def _interpenetrate(a: Piece, b: Piece) -> bool:
    """Whether two pieces' boxes overlap by more than ``OVERLAP_TOLERANCE``: their height intervals, and their
    footprints (``footprints_within``)."""
    za, zb = a.position[2], b.position[2]
    if abs(za - zb) >= a.half_extents[2] + b.half_extents[2] - OVERLAP_TOLERANCE:
        return False
    return footprints_within(a, b, -OVERLAP_TOLERANCE)


def footprints_within(a: Piece, b: Piece, gap: float) -> bool:
    """Whether two pieces' footprints come closer than ``gap`` (metres; negative: overlap by more than its
    size) along every edge normal of either: the separating axis test for rectangles, whose gap along an axis
    is never more than their true distance."""
    ca, cb = a.corners(), b.corners()
    for corners in (ca, cb):
        for k in range(2):
            edge = corners[k + 1] - corners[k]
            normal = np.array([-edge[1], edge[0]]) / np.linalg.norm(edge)
            pa, pb = ca @ normal, cb @ normal
            if max(pb.min() - pa.max(), pa.min() - pb.max()) >= gap:
                return False
    return True


def structure_scene(base: SceneConfig, structure: Structure) -> SceneConfig:
    """``base`` with one object slot per piece of ``structure`` (its scaffold's too), no coloured blocks, and
    the structures' physics (``STRUCTURE_PHYSICS``)."""
    return replace(base, n_blocks=0, n_objects=len(structure.kinds), **STRUCTURE_PHYSICS)
