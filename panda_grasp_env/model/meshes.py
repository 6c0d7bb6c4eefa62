"""The procedural mesh object set: the 1,000 random objects of ``pybullet_data/random_urdfs/000-999``.

These are the objects of vision-based grasping work in that line (Quillen et al. 2018 trained on 900 and held
out 100).  They ship inside the ``pybullet`` wheel (the ``objects`` extra: ``pip install
'panda_grasp_env[objects]'``); nothing is downloaded.  Each object is one OBJ file whose named groups
(``o convex_<k>``) are its convex pieces, 1-10 of them: the set comes decomposed (every piece of a sample of
143 objects is watertight with volume / hull volume >= 0.999999).  930 of the 999 usable objects have at most
``MAX_PARTS`` pieces, and each piece becomes one MuJoCo mesh geom, exactly.  The other 69 are thin shells tiled
by 18-127 small pieces; their pieces are merged into ``MAX_PARTS`` groups of neighbours (k-means++ on the
pieces' centres, seeded), each a geom that collides as the hull of its group, which fills part of their
hollows.  (CoACD at fast settings gave such objects hulls as full -- 0.36-0.62 of the whole hull's volume
where the pieces hold 0.07-0.10 -- at 2-19 s an object, against milliseconds.)  Every geom renders the
original pieces' faces, so the visual geometry is the original mesh.

Frames and units: an object's own frame is its principal frame: origin at its centre of mass (uniform
density), axes along its principal axes of inertia (right-handed), so that the body's inertial frame is its
own; vertices are in metres.  The **scaling rule**: the URDF's scale (0.015), shrunk
where needed so that the middle one of the object's three principal extents is at most
``MAX_MIDDLE_EXTENT``; whichever side it rests on, one horizontal direction is then at most that wide, and the
Panda's 73 mm opening closes across it in a top-down grasp.  Mass is the pieces' volume times a density drawn
per episode from ``DENSITY_RANGE`` (where ``ObjectSpec.mass`` does not fix it); pieces that overlap count twice.

The **split** is fixed: objects 900-999 are the test set, 0-899 train (the published 900 / 100 split, as
numbered).  Object 168 is left out of train: every vertex of its OBJ is NaN.  Four train objects are flat
(295, 297, 602, 824: 0.5-1.5 mm thick, 8-17 mm across) and cannot be picked up from a table; they stay in the
split as published, and the train objects the benchmarks play (``EVALUATION_OBJECTS``) hold none.
"""

from __future__ import annotations

import hashlib
from collections.abc import Callable
from dataclasses import dataclass
from functools import cache
from pathlib import Path
from typing import Any

import mujoco
import numpy as np
from scipy.cluster.vq import kmeans2
from scipy.spatial import ConvexHull

#: Mesh sets ``ObjectSpec(shape="mesh", set=...)`` accepts.
MESH_SETS = ("random_urdfs",)
#: The fixed split of ``random_urdfs``: object ids per split.  Training, tuning and selection touch train only.
SPLITS: dict[str, tuple[int, ...]] = {
    "train": tuple(i for i in range(900) if i != 168),
    "test": tuple(range(900, 1000)),
}
#: Objects of the set left out, and why.
EXCLUDED = {168: "every vertex of its OBJ is NaN"}
#: The URDFs' own mesh scale (OBJ units to metres).
SOURCE_SCALE = 0.015
#: Largest middle principal extent after scaling, metres (see the module docstring).
MAX_MIDDLE_EXTENT = 0.055
#: Most geoms an object gets: the geoms each object slot of a mesh scene carries.
MAX_PARTS = 16
#: Density range (kg/m^3) an object's mass is drawn from: light plastic to hard wood.
DENSITY_RANGE = (400.0, 1000.0)
EXTRA_HINT = "pip install 'panda_grasp_env[objects]' (it installs the pybullet wheel, which ships the object set)"


#: The mesh objects the single-object benchmarks sweep: all 100 test objects, and 100 train objects spread
#: over the train split (every ninth; none of the four flat ones).
EVALUATION_OBJECTS = {"train": SPLITS["train"][::9], "test": SPLITS["test"]}


def object_by_seed(split: str) -> Callable[[int], dict[str, Any]]:
    """Reset options giving episode ``seed`` the object ``EVALUATION_OBJECTS[split][seed % 100]``: any 100
    consecutive seeds play each object once."""
    ids = EVALUATION_OBJECTS[split]

    def options(seed: int) -> dict[str, Any]:
        return {"objects": [{"shape": "mesh", "split": split, "ids": [ids[seed % len(ids)]]}]}

    return options


def set_root(mesh_set: str = "random_urdfs") -> Path:
    """The folder of ``mesh_set`` inside the installed ``pybullet_data``; ``ModuleNotFoundError`` naming the
    extra when it is missing."""
    if mesh_set not in MESH_SETS:
        raise ValueError(f"unknown mesh set {mesh_set!r}; valid: {list(MESH_SETS)}")
    try:
        import pybullet_data
    except ModuleNotFoundError:
        raise ModuleNotFoundError(f"the mesh object set needs the objects extra: {EXTRA_HINT}") from None
    return Path(pybullet_data.getDataPath()) / mesh_set


def split_of(object_id: int) -> str:
    """``"train"`` or ``"test"``: the split object ``object_id`` belongs to (``ValueError`` if none)."""
    for name, ids in SPLITS.items():
        if object_id in ids:
            return name
    reason = EXCLUDED.get(object_id, "ids run from 0 to 999")
    raise ValueError(f"mesh object {object_id!r} is in no split ({reason})")


@dataclass(frozen=True)
class MeshPart:
    """One collision geom of an object: its vertices (N, 3; own frame, metres) and the triangles (M, 3, indices
    into them) of the original faces it renders.  It collides as the convex hull of the vertices."""

    vertices: np.ndarray
    faces: np.ndarray


@dataclass(frozen=True)
class MeshObject:
    """One object of the set, scaled by the rule: its collision geoms and mass properties per unit density, in
    its own frame (metres)."""

    id: int
    parts: tuple[MeshPart, ...]
    #: Applied scale (OBJ units to metres).
    scale: float
    #: Summed volume of the original convex pieces, m^3.
    volume: float
    #: Principal moments of inertia per unit density (kg m^2 per kg/m^3), about the own axes.
    unit_moments: np.ndarray
    #: Half extents of the smallest origin-centred box around the object, metres.
    half_extents: np.ndarray
    #: SHA-256 of the source OBJ: what a record of this object refers to.
    source_sha256: str

    @property
    def vertices(self) -> np.ndarray:
        """All geoms' vertices (N, 3), own frame, metres."""
        return np.concatenate([part.vertices for part in self.parts])

    @property
    def bounding_radius(self) -> float:
        """Radius of the smallest origin-centred sphere containing the object, metres."""
        return float(np.linalg.norm(self.vertices, axis=1).max())


def _read_pieces(path: Path) -> list[MeshPart]:
    """Each named group (``o``) of an OBJ as a part: the vertices its faces use (OBJ units) and its faces
    fanned into triangles; groups with non-finite vertices dropped."""
    vertices: list[list[float]] = []
    groups: list[list[list[int]]] = []
    for line in path.read_text().splitlines():
        if line.startswith("v "):
            vertices.append([float(v) for v in line.split()[1:4]])
        elif line.startswith("o ") or (line.startswith("f ") and not groups):
            groups.append([])
        if line.startswith("f "):
            polygon = [int(token.split("/")[0]) - 1 for token in line.split()[1:]]
            groups[-1].extend([polygon[0], polygon[k], polygon[k + 1]] for k in range(1, len(polygon) - 1))
    table = np.asarray(vertices, dtype=float)
    parts = []
    for triangles in groups:
        if not triangles:
            continue
        used, faces = np.unique(np.asarray(triangles), return_inverse=True)
        piece = table[used]
        if np.isfinite(piece).all() and len(piece) >= 4:
            parts.append(MeshPart(piece, faces.reshape(-1, 3)))
    return parts


def _merged(parts: list[MeshPart], count: int) -> list[MeshPart]:
    """``parts`` merged into at most ``count`` groups of neighbours (k-means++ on their centres, seeded)."""
    if len(parts) <= count:
        return parts
    centres = np.array([part.vertices.mean(axis=0) for part in parts])
    labels = kmeans2(centres, count, seed=np.random.default_rng(0), minit="++")[1]
    merged = []
    for label in np.unique(labels):
        members = [part for part, own in zip(parts, labels) if own == label]
        offsets = np.cumsum([0] + [len(part.vertices) for part in members[:-1]])
        merged.append(
            MeshPart(
                np.concatenate([part.vertices for part in members]),
                np.concatenate([part.faces + offset for part, offset in zip(members, offsets)]),
            )
        )
    return merged


def _hull_mass_properties(points: np.ndarray) -> tuple[float, np.ndarray, np.ndarray]:
    """Volume, first moment (integral of x dV) and second moment (integral of x x^T dV) of the convex hull of
    ``points`` (metres), by tetrahedra from an interior point."""
    hull = ConvexHull(points)
    apex = points[hull.vertices].mean(axis=0)
    triangles = points[hull.simplices]
    corners = np.concatenate([np.broadcast_to(apex, (len(triangles), 1, 3)), triangles], axis=1)
    volumes = np.abs(np.linalg.det(corners[:, 1:] - corners[:, :1])) / 6.0
    first = (volumes[:, None] * corners.mean(axis=1)).sum(axis=0)
    summed = corners.sum(axis=1)
    # For a tetrahedron with corners p_i: integral of x x^T dV = V / 20 (sum p_i p_i^T + (sum p_i)(sum p_i)^T).
    outer = np.einsum("tci,tcj->tij", corners, corners) + np.einsum("ti,tj->tij", summed, summed)
    return float(volumes.sum()), first, np.einsum("t,tij->ij", volumes / 20.0, outer)


@cache
def load_mesh_object(object_id: int, mesh_set: str = "random_urdfs") -> MeshObject:
    """Object ``object_id`` of ``mesh_set``, scaled by the rule (cached per process)."""
    split_of(object_id)
    path = set_root(mesh_set) / f"{object_id:03d}" / f"{object_id:03d}.obj"
    pieces = _read_pieces(path)
    if not pieces:
        raise ValueError(f"mesh object {object_id}: no usable piece in {path}")
    points = np.concatenate([piece.vertices for piece in pieces]) * SOURCE_SCALE
    centred = points - points.mean(axis=0)
    principal = np.linalg.svd(centred, full_matrices=False)[2]
    middle_extent = np.sort(np.ptp(centred @ principal.T, axis=0))[1]
    scale = SOURCE_SCALE * min(1.0, MAX_MIDDLE_EXTENT / middle_extent)
    pieces = [MeshPart(piece.vertices * scale, piece.faces) for piece in pieces]
    volume, first, second = 0.0, np.zeros(3), np.zeros((3, 3))
    for piece in pieces:
        v, f, s = _hull_mass_properties(piece.vertices)
        volume, first, second = volume + v, first + f, second + s
    com = first / volume
    covariance = second - volume * np.outer(com, com)  # about the centre of mass
    moments, axes = np.linalg.eigh(np.trace(covariance) * np.eye(3) - covariance)
    axes[:, 2] *= np.sign(np.linalg.det(axes))  # right-handed
    pieces = [MeshPart((piece.vertices - com) @ axes, piece.faces) for piece in pieces]  # into the principal frame
    extent = np.abs(np.concatenate([piece.vertices for piece in pieces])).max(axis=0)
    digest = hashlib.sha256(path.read_bytes()).hexdigest()
    return MeshObject(object_id, tuple(_merged(pieces, MAX_PARTS)), scale, volume, moments, extent, digest)


def add_mesh_assets(spec: mujoco.MjSpec, object_ids: tuple[int, ...]) -> list[str]:
    """Add the geoms' meshes of objects ``object_ids`` to ``spec`` as assets (each renders its original faces
    and collides as its hull); their names."""
    names = []
    for object_id in object_ids:
        for index, part in enumerate(load_mesh_object(object_id).parts):
            mesh = spec.add_mesh()
            mesh.name = mesh_name(object_id, index)
            mesh.uservert = part.vertices.ravel().tolist()
            mesh.userface = part.faces.ravel().tolist()
            mesh.inertia = mujoco.mjtMeshInertia.mjMESH_INERTIA_CONVEX  # mass comes from MeshObject, per object
            names.append(mesh.name)
    return names


def mesh_name(object_id: int, part: int) -> str:
    """The MuJoCo mesh asset of one of an object's geoms."""
    return f"random_urdfs_{object_id:03d}_{part}"
