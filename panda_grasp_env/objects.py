"""Object shapes for grasping tasks: cubes, boxes, cylinders, spheres and capsules.

A scene has a fixed number of free-object slots (``SceneConfig.n_objects``); a
task gives each slot a shape at every reset by rewriting the slot's geom type,
size, mass and inertia in the compiled model (no recompilation, so renderers
and the controller stay valid).  Sizes are MuJoCo geom sizes: half-extents for
boxes, (radius, half-height) for cylinders and capsules, (radius,) for
spheres -- metres.  The shape's own z axis is "up" when it rests as spawned.
"""

from __future__ import annotations

from dataclasses import dataclass

import mujoco
import numpy as np

SHAPES = ("cube", "box", "cylinder", "sphere", "capsule")
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


@dataclass(frozen=True)
class ObjectShape:
    """One object: ``kind`` in ``SHAPES``, MuJoCo geom ``size`` (metres) and colour (r, g, b in 0-1)."""

    kind: str
    size: tuple[float, ...]
    rgb: tuple[float, float, float] = (0.7, 0.7, 0.7)

    @property
    def geom_size(self) -> np.ndarray:
        """The three-element MuJoCo ``geom_size``."""
        if self.kind == "cube":
            return np.full(3, self.size[0])
        padded = np.zeros(3)
        padded[: len(self.size)] = self.size
        return padded

    @property
    def resting_half_height(self) -> float:
        """Height of the centre above the table when resting as spawned, metres."""
        if self.kind in ("cube", "sphere"):
            return self.size[0]
        if self.kind == "box":
            return self.size[2]
        if self.kind == "cylinder":
            return self.size[1]
        return self.size[0]  # capsule lies on its side

    @property
    def bounding_radius(self) -> float:
        """Radius of the smallest sphere around the shape centre that contains it, metres."""
        size = self.geom_size
        if self.kind in ("cube", "box"):
            return float(np.linalg.norm(size))
        if self.kind == "cylinder":
            return float(np.hypot(size[0], size[1]))
        if self.kind == "capsule":
            return float(size[0] + size[1])
        return float(size[0])

    def width_across(self, yaw: float, direction: float) -> float:
        """Horizontal width (metres) of the shape resting as spawned at ``yaw`` (radians, world; see
        ``tasks.grasp.spawn_quaternion``), measured along the horizontal world direction ``direction`` (radians)."""
        angle = direction - yaw  # the direction in the shape's own frame
        along_x, along_y = abs(np.cos(angle)), abs(np.sin(angle))
        size = self.geom_size
        if self.kind in ("cube", "box"):
            return float(2 * (along_x * size[0] + along_y * size[1]))
        if self.kind == "capsule":  # lies with its axis along its own y
            return float(2 * (size[0] + along_y * size[1]))
        return float(2 * size[0])  # sphere; cylinder standing

    def mass_and_inertia(self) -> tuple[float, np.ndarray]:
        """Mass (kg) and principal moments of inertia (kg m^2) about the shape's own axes."""
        size = self.geom_size
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
        return float(mass), inertia


def sample_shape(
    rng: np.random.Generator,
    kinds: tuple[str, ...] = SHAPES,
    size_ranges: dict[str, tuple[tuple[float, float], ...]] | None = None,
    rgb: tuple[float, float, float] | None = None,
) -> ObjectShape:
    """A random shape: kind uniformly from ``kinds``, each size uniformly in its range."""
    ranges = DEFAULT_SIZE_RANGES | (size_ranges or {})
    kind = str(kinds[rng.integers(len(kinds))])
    size = tuple(float(rng.uniform(low, high)) for low, high in ranges[kind])
    colour = rgb if rgb is not None else PALETTE[int(rng.integers(len(PALETTE)))]
    return ObjectShape(kind, size, colour)


def validate_shape_options(kinds: tuple[str, ...], size_ranges: dict | None) -> None:
    """Raise ``ValueError`` for unknown shape kinds or malformed size ranges."""
    unknown = [k for k in kinds if k not in SHAPES]
    if unknown or not kinds:
        raise ValueError(f"unknown object shape(s) {unknown or kinds}; valid: {list(SHAPES)}")
    for kind, ranges in (size_ranges or {}).items():
        if kind not in SHAPES:
            raise ValueError(f"size_ranges: unknown shape {kind!r}; valid: {list(SHAPES)}")
        expected = len(DEFAULT_SIZE_RANGES[kind])
        if len(ranges) != expected or not all(len(r) == 2 and 0.005 <= r[0] <= r[1] <= 0.07 for r in ranges):
            raise ValueError(
                f"size_ranges[{kind!r}] must be {expected} (low, high) pairs with 0.005 <= low <= high <= 0.07 m, "
                f"got {ranges!r}"
            )


def apply_shape(model: mujoco.MjModel, body_id: int, shape: ObjectShape) -> None:
    """Rewrite a single-geom free body's geom type, size, colour, mass and inertia in place.

    Call ``mujoco.mj_setConst`` afterwards (``Workcell.set_object_shapes`` does).
    """
    geom = model.body_geomadr[body_id]
    size = shape.geom_size
    model.geom_type[geom] = _GEOM_TYPES[shape.kind]
    model.geom_size[geom] = size
    model.geom_rbound[geom] = shape.bounding_radius
    if shape.kind in ("cube", "box"):
        half_extent = size
    elif shape.kind == "sphere":
        half_extent = np.full(3, size[0])
    elif shape.kind == "cylinder":
        half_extent = np.array([size[0], size[0], size[1]])
    else:
        half_extent = np.array([size[0], size[0], size[0] + size[1]])
    model.geom_aabb[geom] = np.concatenate([np.zeros(3), half_extent])
    model.geom_rgba[geom] = [*shape.rgb, 1.0]
    mass, inertia = shape.mass_and_inertia()
    model.body_mass[body_id] = mass
    model.body_inertia[body_id] = inertia
    model.body_ipos[body_id] = 0.0
    model.body_iquat[body_id] = [1.0, 0.0, 0.0, 0.0]
