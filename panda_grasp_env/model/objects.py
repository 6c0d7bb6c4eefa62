"""Object shapes for grasping tasks: cubes, boxes, cylinders, spheres, capsules, and meshes of the procedural
object set (``panda_grasp_env.model.meshes``).

A scene has a fixed number of free-object slots (``SceneConfig.n_objects``); a
task gives each slot a shape at every reset by rewriting the slot's geom type,
size, mass and inertia in the compiled model (no recompilation, so renderers
and the controller stay valid).  Sizes are MuJoCo geom sizes: half-extents for
boxes, (radius, half-height) for cylinders and capsules, (radius,) for
spheres -- metres.  The shape's own z axis is "up" when it rests as spawned.
A mesh object takes a slot through its mesh geoms (``SceneConfig.mesh_objects`` compiles them in); its
``size`` is the half extents of its bounding box, and it is dropped at an orientation drawn per episode.
"""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass, fields
from typing import Any

import mujoco
import numpy as np
from scipy.spatial.transform import Rotation

from panda_grasp_env.geometry import half_extent_along, is_number, lying_quaternion, yaw_quaternion
from panda_grasp_env.model.meshes import DENSITY_RANGE, MESH_SETS, SPLITS, load_mesh_object, mesh_name, split_of
from panda_grasp_env.model.scene import HIDDEN_GROUP

#: The primitive shapes (the kind one-hot of ``Grasp``'s object properties); ``"mesh"`` draws from a mesh set.
SHAPES = ("cube", "box", "cylinder", "sphere", "capsule")
KINDS = (*SHAPES, "mesh")
#: Density of every object, kg/m^3 (hard wood): a 5 cm cube weighs 0.1 kg.
DENSITY = 800.0
#: Default size ranges per shape, metres (see ``ObjectShape.size``): all fit the 73 mm hand opening.
DEFAULT_SIZE_RANGES: dict[str, tuple[tuple[float, float], ...]] = {
    "cube": ((0.015, 0.03),),  # half edge
    "box": ((0.012, 0.03), (0.02, 0.05), (0.015, 0.035)),  # half extents x, y, z
    "cylinder": ((0.015, 0.03), (0.015, 0.04)),  # radius, half height (standing)
    "sphere": ((0.018, 0.03),),  # radius
    "capsule": ((0.012, 0.022), (0.015, 0.035)),  # radius, half length of the straight part (lying)
}
PALETTE = (
    (0.85, 0.12, 0.10),
    (0.10, 0.70, 0.20),
    (0.10, 0.25, 0.85),
    (0.95, 0.85, 0.10),
    (0.90, 0.45, 0.05),
    (0.60, 0.15, 0.75),
    (0.05, 0.75, 0.80),
    (0.95, 0.45, 0.70),
    (0.55, 0.35, 0.15),
    (0.50, 0.85, 0.35),
)
_GEOM_TYPES = {
    "cube": mujoco.mjtGeom.mjGEOM_BOX,
    "box": mujoco.mjtGeom.mjGEOM_BOX,
    "cylinder": mujoco.mjtGeom.mjGEOM_CYLINDER,
    "sphere": mujoco.mjtGeom.mjGEOM_SPHERE,
    "capsule": mujoco.mjtGeom.mjGEOM_CAPSULE,
}


#: Resting poses: ``standing`` (the shape's own z axis up) or ``lying`` (its z axis horizontal: a cylinder or
#: capsule on its side, a box on a side face); ``random`` draws one per episode; ``default``: capsules lie,
#: every other shape stands.
POSES = ("default", "standing", "lying", "random")
#: Object masses (kg) and sliding friction coefficients ``ObjectSpec`` accepts.
MASS_RANGE, FRICTION_RANGE = (0.005, 2.0), (0.05, 2.0)
#: Largest size component (metres) ``ObjectSpec`` accepts: what the 73 mm hand opening can still hold.
MAX_SIZE = 0.07


@dataclass(frozen=True)
class ObjectShape:
    """One object as drawn for an episode: ``kind`` in ``KINDS``, MuJoCo geom ``size`` (metres; a mesh's: the
    half extents of its bounding box), colour (r, g, b in 0-1), and the physics ``ObjectSpec`` may set (None:
    the defaults)."""

    kind: str
    size: tuple[float, ...]
    rgb: tuple[float, float, float] = (0.7, 0.7, 0.7)
    #: kg; None: ``DENSITY`` times the volume (a mesh's is always drawn).
    mass: float | None = None
    #: Sliding friction in effect against the table, the fingers and fixtures; None: the scene's (a contact
    #: takes the larger coefficient of its two geoms: the table's 1.0, the finger pads' 1.5).
    friction: float | None = None
    #: Rests on its side (own z axis horizontal); None: capsules lie, every other shape stands.
    lying: bool | None = None
    #: A mesh's object id in its set (``meshes.load_mesh_object``).
    mesh: int | None = None
    #: A mesh's orientation (w, x, y, z) before its heading, as it is dropped: drawn uniformly per episode.
    orientation: tuple[float, float, float, float] | None = None

    @property
    def is_lying(self) -> bool:
        if self.kind == "mesh":
            return False
        return self.kind == "capsule" if self.lying is None else self.lying

    @property
    def geom_size(self) -> np.ndarray:
        """The three-element MuJoCo ``geom_size`` (a mesh's: ``size``)."""
        if self.kind == "cube":
            return np.full(3, self.size[0])
        padded = np.zeros(3)
        padded[: len(self.size)] = self.size
        return padded

    def resting_quaternion(self, yaw: float) -> np.ndarray:
        """Orientation (w, x, y, z) resting on the table at heading ``yaw`` (radians): standing, or lying --
        turned a quarter about its own x axis first (its y axis then points up); a mesh at its drawn
        ``orientation``, turned to ``yaw`` about world z (it may tip over when released)."""
        if self.kind == "mesh":
            tumbled = Rotation.from_quat(self.orientation, scalar_first=True)
            return (Rotation.from_euler("z", yaw) * tumbled).as_quat(scalar_first=True)
        return lying_quaternion(yaw) if self.is_lying else yaw_quaternion(yaw)

    def _mesh_vertices(self, yaw: float = 0.0) -> np.ndarray:
        """A mesh's vertices (N, 3) turned as it rests at ``yaw``, relative to its centre, metres."""
        rotation = Rotation.from_quat(self.resting_quaternion(yaw), scalar_first=True)
        return rotation.apply(load_mesh_object(self.mesh).vertices)

    @property
    def resting_half_height(self) -> float:
        """Height of the centre above the table when resting as spawned, metres."""
        size = self.geom_size
        if self.kind == "mesh":
            return float(-self._mesh_vertices()[:, 2].min())
        if self.kind in ("cube", "sphere"):
            return float(size[0])
        if self.is_lying:
            return float(size[1] if self.kind == "box" else size[0])  # box on a side face; round side down
        if self.kind == "capsule":
            return float(size[0] + size[1])
        return float(size[2] if self.kind == "box" else size[1])

    @property
    def bounding_radius(self) -> float:
        """Radius of the smallest sphere around the shape centre that contains it, metres."""
        size = self.geom_size
        if self.kind == "mesh":
            return load_mesh_object(self.mesh).bounding_radius
        if self.kind in ("cube", "box"):
            return float(np.linalg.norm(size))
        if self.kind == "cylinder":
            return float(np.hypot(size[0], size[1]))
        if self.kind == "capsule":
            return float(size[0] + size[1])
        return float(size[0])

    def width_across(self, yaw: float, direction: float) -> float:
        """Horizontal width (metres) of the shape resting as spawned at ``yaw`` (radians, world), measured
        along the horizontal world direction ``direction`` (radians)."""
        axis = np.array([np.cos(direction), np.sin(direction), 0.0])
        if self.kind == "mesh":
            return float(np.ptp(self._mesh_vertices(yaw) @ axis))
        rotation = Rotation.from_quat(self.resting_quaternion(yaw), scalar_first=True).as_matrix()
        return 2 * half_extent_along("box" if self.kind == "cube" else self.kind, self.geom_size, rotation, axis)

    def mass_and_inertia(self) -> tuple[float, np.ndarray]:
        """Mass (kg) and principal moments of inertia (kg m^2) about the shape's own axes (uniform density)."""
        size = self.geom_size
        if self.kind == "mesh":
            mesh = load_mesh_object(self.mesh)
            return float(self.mass), mesh.unit_moments * (self.mass / mesh.volume)
        if self.kind in ("cube", "box"):
            mass = DENSITY * 8 * np.prod(size)
            full = 2 * size
            inertia = (
                mass
                / 12
                * np.array([full[1] ** 2 + full[2] ** 2, full[0] ** 2 + full[2] ** 2, full[0] ** 2 + full[1] ** 2])
            )
        elif self.kind == "sphere":
            mass = DENSITY * 4 / 3 * np.pi * size[0] ** 3
            inertia = np.full(3, 0.4 * mass * size[0] ** 2)
        elif self.kind == "cylinder":
            radius, half = size[0], size[1]
            mass = DENSITY * np.pi * radius**2 * 2 * half
            side = mass * (3 * radius**2 + (2 * half) ** 2) / 12
            inertia = np.array([side, side, 0.5 * mass * radius**2])
        else:  # capsule: a cylinder plus two hemispherical caps
            radius, half = size[0], size[1]
            body_mass = DENSITY * np.pi * radius**2 * 2 * half
            cap_mass = DENSITY * 2 / 3 * np.pi * radius**3  # each
            mass = body_mass + 2 * cap_mass
            cap_side = 83 / 320 * cap_mass * radius**2 + cap_mass * (half + 3 * radius / 8) ** 2
            side = body_mass * (3 * radius**2 + (2 * half) ** 2) / 12 + 2 * cap_side
            axial = 0.5 * body_mass * radius**2 + 2 * 0.4 * cap_mass * radius**2
            inertia = np.array([side, side, axial])
        if self.mass is not None:  # the same shape at another density
            inertia = inertia * (self.mass / mass)
            mass = self.mass
        return float(mass), inertia


#: A value fixed, or a ``(low, high)`` range drawn uniformly per episode.
Value = float | tuple[float, float]


def _checked_value(value: Any, low: float, high: float, name: str) -> Value:
    """``value`` as a float or an ordered (low, high) pair within [low, high]; ``ValueError`` naming it."""
    pair = tuple(value) if isinstance(value, (tuple, list)) else (value, value)
    valid = len(pair) == 2 and all(map(is_number, pair)) and low <= pair[0] <= pair[1] <= high
    if not valid:
        raise ValueError(f"{name} must be a number or a (low, high) range within [{low}, {high}], got {value!r}")
    return (float(pair[0]), float(pair[1])) if isinstance(value, (tuple, list)) else float(pair[0])


def _draw(rng: np.random.Generator, value: Value) -> float:
    return float(rng.uniform(*value)) if isinstance(value, tuple) else value


@dataclass(frozen=True)
class ObjectSpec:
    """How to draw one object at each reset.  Every number is fixed, or a ``(low, high)`` range drawn
    uniformly per episode from the env's seeded generator.  Also accepted as a plain dict of these fields
    (``gym.make(..., objects=[{"shape": "cube", "mass": 0.4}])``).

    Fields: ``shape``: a kind from ``SHAPES`` or several, drawn uniformly; ``size``: the MuJoCo geom size
    (metres; half-extents, radius and half-height, ...) as one value or range per component -- for one
    kind, or a mapping kind -> components; None: ``DEFAULT_SIZE_RANGES``; ``mass`` (kg; None: 800 kg/m^3);
    ``friction``: the sliding coefficient in effect against the table, the fingers and fixtures (None: the
    scene's); ``rgb`` (three values or ranges in 0-1; None: a ``PALETTE`` colour); ``pose`` (``POSES``);
    ``yaw``: heading on the table, radians (spread-out objects; a clutter heap drops them at any yaw).
    ``shape="mesh"`` draws an object of the mesh ``set`` (``meshes.MESH_SETS``): one of ``ids`` (default: all
    of ``split``, ``"train"`` or ``"test"``; ids must belong to ``split``), at an orientation drawn uniformly
    (it falls onto a resting face), with a mass of its volume times a density drawn from
    ``meshes.DENSITY_RANGE`` unless ``mass`` is given; it takes no ``size`` and rests as it falls (``pose``
    ``default`` or ``random``).  Needs the ``objects`` extra.
    """

    shape: str | tuple[str, ...] = SHAPES
    size: tuple[Value, ...] | Mapping[str, tuple[Value, ...]] | None = None
    mass: Value | None = None
    friction: Value | None = None
    rgb: tuple[Value, Value, Value] | None = None
    pose: str = "default"
    yaw: Value = (-np.pi / 4, np.pi / 4)
    set: str = "random_urdfs"
    split: str = "train"
    ids: tuple[int, ...] | None = None

    def __post_init__(self) -> None:
        kinds = (self.shape,) if isinstance(self.shape, str) else tuple(self.shape)
        if not kinds or not all(isinstance(k, str) and k in KINDS for k in kinds):
            raise ValueError(f"shape must be one or more of {list(KINDS)}, got {self.shape!r}")
        object.__setattr__(self, "shape", kinds)
        self._check_mesh_fields()
        size = self.size
        if size is not None and not isinstance(size, Mapping):
            if len(kinds) != 1:
                raise ValueError(f"size as components needs one shape, not {list(kinds)}: give a mapping shape -> size")
            size = {kinds[0]: size}
        if size is not None:
            unknown = [k for k in size if k not in SHAPES]  # a mesh's size is its own
            if unknown:
                raise ValueError(f"size: unknown shape(s) {unknown}; valid: {list(SHAPES)}")
            unused = [k for k in size if k not in kinds]  # a size for a shape never drawn would be ignored
            if unused:
                raise ValueError(f"size: shape(s) {unused} are not among the spec's shapes {list(kinds)}")
            checked = {}
            for kind, components in size.items():
                expected = len(DEFAULT_SIZE_RANGES[kind])
                if not isinstance(components, (tuple, list)) or len(components) != expected:
                    raise ValueError(f"size[{kind!r}] must have {expected} component(s), got {components!r}")
                checked[kind] = tuple(
                    _checked_value(c, 0.005, MAX_SIZE, f"size[{kind!r}][{i}]") for i, c in enumerate(components)
                )
            size = checked
        object.__setattr__(self, "size", size)
        for name, (low, high) in (("mass", MASS_RANGE), ("friction", FRICTION_RANGE)):
            if getattr(self, name) is not None:
                object.__setattr__(self, name, _checked_value(getattr(self, name), low, high, name))
        if self.rgb is not None:
            if not isinstance(self.rgb, (tuple, list)) or len(self.rgb) != 3:
                raise ValueError(f"rgb must be three values or ranges in [0, 1], got {self.rgb!r}")
            object.__setattr__(self, "rgb", tuple(_checked_value(c, 0.0, 1.0, "rgb") for c in self.rgb))
        if self.pose not in POSES:
            raise ValueError(f"pose must be one of {list(POSES)}, got {self.pose!r}")
        if "mesh" in self.shape and self.pose in ("standing", "lying"):
            raise ValueError(f'pose {self.pose!r}: a mesh object rests as it falls (pose "default" or "random")')
        object.__setattr__(self, "yaw", _checked_value(self.yaw, -np.pi, np.pi, "yaw"))

    def _check_mesh_fields(self) -> None:
        """``set``, ``split`` and ``ids`` valid (``ValueError`` naming the field); ids stored as a sorted tuple."""
        if self.set not in MESH_SETS:
            raise ValueError(f"set must be one of {list(MESH_SETS)}, got {self.set!r}")
        if self.split not in SPLITS:
            raise ValueError(f"split must be one of {list(SPLITS)}, got {self.split!r}")
        if self.ids is None:
            return
        ids = [self.ids] if isinstance(self.ids, (int, np.integer)) else self.ids
        if (
            not isinstance(ids, (tuple, list))
            or not ids
            or not all(isinstance(i, (int, np.integer)) and not isinstance(i, bool) for i in ids)
        ):
            raise ValueError(f"ids must be a non-empty list of mesh object ids, got {self.ids!r}")
        outside = sorted({int(i) for i in ids} - set(SPLITS[self.split]))
        if outside:
            reasons = []
            for i in outside[:5]:
                try:
                    reasons.append(f"{i} is in {split_of(i)}")
                except ValueError as error:
                    reasons.append(str(error))
            raise ValueError(f"ids {outside} are not in split {self.split!r} ({'; '.join(reasons)})")
        if "mesh" not in self.shape:
            raise ValueError('ids are mesh object ids: give them with shape="mesh"')
        object.__setattr__(self, "ids", tuple(sorted({int(i) for i in ids})))

    @property
    def mesh_ids(self) -> tuple[int, ...]:
        """The mesh objects this spec may draw (none without ``"mesh"`` among its shapes)."""
        if "mesh" not in self.shape:
            return ()
        return self.ids if self.ids is not None else SPLITS[self.split]

    @classmethod
    def of(cls, value: ObjectSpec | Mapping[str, Any]) -> ObjectSpec:
        """``value`` as a spec: a spec, or a dict of its fields (``ValueError`` naming unknown keys)."""
        if isinstance(value, ObjectSpec):
            return value
        if not isinstance(value, Mapping):
            raise ValueError(f"an object spec must be an ObjectSpec or a dict of its fields, got {value!r}")
        unknown = sorted(set(value) - {f.name for f in fields(cls)})
        if unknown:
            raise ValueError(f"unknown object spec key(s) {unknown}; valid: {[f.name for f in fields(cls)]}")
        return cls(**value)

    def sample(self, rng: np.random.Generator) -> ObjectShape:
        """Draw an object: kind, size, colour, then mass, friction and pose where they are ranges or random."""
        kind = str(self.shape[rng.integers(len(self.shape))])
        if kind == "mesh":
            return self._sample_mesh(rng)
        ranges = DEFAULT_SIZE_RANGES | (self.size or {})
        size = tuple(_draw(rng, component) for component in ranges[kind])
        if self.rgb is None:
            rgb = PALETTE[int(rng.integers(len(PALETTE)))]
        else:
            rgb = tuple(_draw(rng, component) for component in self.rgb)
        mass = None if self.mass is None else _draw(rng, self.mass)
        friction = None if self.friction is None else _draw(rng, self.friction)
        lying = {"default": None, "standing": False, "lying": True}.get(self.pose)
        if self.pose == "random":
            lying = bool(rng.random() < 0.5)
        return ObjectShape(kind, size, rgb, mass, friction, lying)

    def _sample_mesh(self, rng: np.random.Generator) -> ObjectShape:
        """Draw a mesh object: id, colour, orientation, then mass (or density) and friction."""
        ids = self.mesh_ids
        mesh = load_mesh_object(int(ids[rng.integers(len(ids))]), self.set)
        if self.rgb is None:
            rgb = PALETTE[int(rng.integers(len(PALETTE)))]
        else:
            rgb = tuple(_draw(rng, component) for component in self.rgb)
        orientation = tuple(Rotation.random(rng=rng).as_quat(scalar_first=True))
        mass = mesh.volume * rng.uniform(*DENSITY_RANGE) if self.mass is None else _draw(rng, self.mass)
        friction = None if self.friction is None else _draw(rng, self.friction)
        return ObjectShape("mesh", tuple(mesh.half_extents), rgb, float(mass), friction, None, mesh.id, orientation)

    def sample_yaw(self, rng: np.random.Generator) -> float:
        """A resting heading, radians."""
        return float(rng.uniform(*self.yaw)) if isinstance(self.yaw, tuple) else self.yaw


def apply_shape(model: mujoco.MjModel, body_id: int, shape: ObjectShape) -> None:
    """Rewrite an object slot's geoms, colour, mass and inertia in place for ``shape``.

    The slot's first geom is its primitive one; a slot of a mesh scene also carries mesh geoms
    (``SceneConfig.mesh_objects``).  A primitive shape takes the first geom and hides the mesh geoms; a mesh
    takes as many mesh geoms as it has parts and hides the rest, and its first geom becomes a hidden box around
    it without contacts (what ``park`` and reach checks read).  Call ``mujoco.mj_setConst``
    afterwards (``Workcell.set_object_shapes`` does).
    """
    geom = int(model.body_geomadr[body_id])
    parts = range(geom + 1, geom + int(model.body_geomnum[body_id]))
    size = shape.geom_size
    is_mesh = shape.kind == "mesh"
    model.geom_type[geom] = mujoco.mjtGeom.mjGEOM_BOX if is_mesh else _GEOM_TYPES[shape.kind]
    model.geom_size[geom] = size
    model.geom_rbound[geom] = shape.bounding_radius
    if shape.kind in ("cube", "box", "mesh"):
        half_extent = size
    elif shape.kind == "sphere":
        half_extent = np.full(3, size[0])
    elif shape.kind == "cylinder":
        half_extent = np.array([size[0], size[0], size[1]])
    else:
        half_extent = np.array([size[0], size[0], size[0] + size[1]])
    model.geom_aabb[geom] = np.concatenate([np.zeros(3), half_extent])
    model.geom_rgba[geom] = [*shape.rgb, 1.0]
    _set_shown(model, geom, not is_mesh)
    used = len(load_mesh_object(shape.mesh).parts) if is_mesh else 0
    if used > len(parts):
        raise ValueError(f"object slot {body_id} has no mesh geoms: build the scene with mesh_objects")
    for index, part in enumerate(parts):
        _set_shown(model, part, index < used)
        if index < used:
            _set_mesh(model, part, mujoco.mj_name2id(model, mujoco.mjtObj.mjOBJ_MESH, mesh_name(shape.mesh, index)))
            model.geom_rgba[part] = [*shape.rgb, 1.0]
    mass, inertia = shape.mass_and_inertia()
    model.body_mass[body_id] = mass
    model.body_inertia[body_id] = inertia
    model.body_ipos[body_id] = 0.0  # a mesh's own frame is its principal frame too
    model.body_iquat[body_id] = [1.0, 0.0, 0.0, 0.0]


def _set_shown(model: mujoco.MjModel, geom: int, shown: bool) -> None:
    """Draw a slot geom and give it contacts (group 0, contype and conaffinity 1), or hide it without any."""
    model.geom_contype[geom] = model.geom_conaffinity[geom] = int(shown)
    model.geom_group[geom] = 0 if shown else HIDDEN_GROUP


def _set_mesh(model: mujoco.MjModel, geom: int, mesh: int) -> None:
    """Make ``geom`` show and collide as compiled mesh ``mesh``: the mesh frame's offset from the body (MuJoCo
    centres and aligns each mesh), bounding sphere and box."""
    start, count = model.mesh_vertadr[mesh], model.mesh_vertnum[mesh]
    vertices = model.mesh_vert[start : start + count]
    low, high = vertices.min(axis=0), vertices.max(axis=0)
    model.geom_dataid[geom] = mesh
    model.geom_pos[geom], model.geom_quat[geom] = model.mesh_pos[mesh], model.mesh_quat[mesh]
    model.geom_size[geom] = (high - low) / 2
    model.geom_rbound[geom] = float(np.linalg.norm(vertices, axis=1).max())
    model.geom_aabb[geom] = np.concatenate([(low + high) / 2, (high - low) / 2])
