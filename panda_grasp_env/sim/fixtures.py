"""A task's fixtures in the live simulation (``Task.add_fixtures``: a bin, a wall, a shelf): which geoms they
are, how high they stand, which one is below a point, and moving and resizing them per episode without
recompiling.  World frame, metres, radians.
"""

from __future__ import annotations

from collections.abc import Iterable, Sequence

import mujoco
import numpy as np

from panda_grasp_env.geometry import yaw_quaternion
from panda_grasp_env.model.scene import fixture_geoms, fixture_name
from panda_grasp_env.sim.extents import geom_extent_along

#: Geom groups downward ray casts see: group 0 only, the table, objects and fixtures (not the robot).
WORLD_GROUP = np.array([1, 0, 0, 0, 0, 0], dtype=np.uint8)


class Fixtures:
    """The fixtures of one simulation (``model``, ``data``); ``robot_bodies`` and ``objects`` (the free bodies) are
    body ids that are not fixtures."""

    def __init__(
        self, model: mujoco.MjModel, data: mujoco.MjData, robot_bodies: Iterable[int], objects: Iterable[int]
    ) -> None:
        self.model, self.data = model, data
        self._robot_bodies, self._objects = set(robot_bodies), {int(b) for b in objects}
        #: The fixtures' collision geoms, and each one's fixture name (its body's, or its own for a geom of the
        #: world body).
        self.geom_ids = fixture_geoms(model)
        self.names = {int(g): fixture_name(model, g) for g in self.geom_ids}
        #: The collision geoms standing on the table, as (x, y, reach, top) in metres: transit heights clear
        #: them as they clear objects (kept current by ``set_pose``/``set_size``; from the kinematics as they
        #: stand at construction).
        self.tops = self._tops()

    def _tops(self) -> list[tuple[float, float, float, float]]:
        model, data = self.model, self.data
        fixtures = []
        for g in self.geom_ids:
            top = geom_extent_along(model, data, g, np.array([0.0, 0.0, 1.0]))[1]
            if top > 1e-6:  # the table's top is the zero of heights: a fixture below it is out of the way
                fixtures.append((*map(float, data.geom_xpos[g][:2]), float(model.geom_rbound[g]), top))
        return fixtures

    def set_pose(
        self, name: str, position: Sequence[float], yaw: float = 0.0, quaternion: Sequence[float] | None = None
    ) -> None:
        """Move fixture ``name`` (a fixture body, or a fixture geom of the world body) to ``position`` (world,
        metres: the body's frame, or the geom's centre) turned by ``yaw`` about world z (radians), or to
        ``quaternion`` (w, x, y, z) if given.  For a task's ``reset``: the model changes, nothing is
        recompiled, and heights, ray casts, transit clearance and the motion planner's model follow."""
        position = np.asarray(position, dtype=float)
        if position.shape != (3,) or not np.all(np.isfinite(position)) or not np.isfinite(yaw):
            raise ValueError(
                f"fixture {name!r}: position must be 3 finite metres and yaw finite, got {position}, {yaw}"
            )
        orientation = yaw_quaternion(yaw) if quaternion is None else np.asarray(quaternion, dtype=float)
        if orientation.shape != (4,) or not np.isclose(np.linalg.norm(orientation), 1.0):
            raise ValueError(f"fixture {name!r}: quaternion must be a unit (w, x, y, z), got {quaternion!r}")
        body = mujoco.mj_name2id(self.model, mujoco.mjtObj.mjOBJ_BODY, name)
        if body > 0 and self.model.body_weldid[body] == 0 and body not in self._robot_bodies:  # a static body
            self.model.body_pos[body], self.model.body_quat[body] = position, orientation
        else:
            geom = self._world_geom(name)
            self.model.geom_pos[geom], self.model.geom_quat[geom] = position, orientation
        self._changed()

    def set_size(self, geom_name: str, size: Sequence[float]) -> None:
        """Resize a fixture's collision geom ``geom_name`` (box, sphere, capsule, cylinder or ellipsoid: MuJoCo's
        ``size`` of that type, metres) without recompiling; its bounding sphere and box follow.  For a task's
        ``reset``, like ``set_pose``."""
        geom = mujoco.mj_name2id(self.model, mujoco.mjtObj.mjOBJ_GEOM, geom_name)
        if geom not in self.names:
            raise ValueError(f"unknown fixture geom {geom_name!r}; valid: {self._named_geoms()}")
        bounds = _primitive_bounds(int(self.model.geom_type[geom]), size)
        if bounds is None:
            raise ValueError(
                f"fixture geom {geom_name!r}: a size of 1-3 positive metres fitting its type is needed, and only "
                f"boxes, spheres, capsules, cylinders and ellipsoids resize without recompiling; got {size!r}"
            )
        self.model.geom_size[geom], self.model.geom_rbound[geom], self.model.geom_aabb[geom, 3:] = bounds
        self._changed()

    def _world_geom(self, name: str) -> int:
        geom = mujoco.mj_name2id(self.model, mujoco.mjtObj.mjOBJ_GEOM, name)
        if geom not in self.names or self.model.geom_bodyid[geom] != 0:
            bodies = sorted({n for g, n in self.names.items() if self.model.geom_bodyid[g] != 0})
            world = [n for n in self._named_geoms() if self.model.geom(n).bodyid[0] == 0]
            raise ValueError(f"unknown fixture {name!r}; fixture bodies: {bodies}, fixture geoms of the world: {world}")
        return geom

    def _named_geoms(self) -> list[str]:
        names = (mujoco.mj_id2name(self.model, mujoco.mjtObj.mjOBJ_GEOM, int(g)) for g in self.geom_ids)
        return sorted(n for n in names if n)

    def _changed(self) -> None:
        mujoco.mj_kinematics(self.model, self.data)  # geom poses (ray casts, heights) as the model now says
        self.tops = self._tops()

    def below(self, x: float, y: float) -> str | None:
        """The fixture whose surface is the first one straight below (x, y) once free objects are seen through
        (what a primitive at (x, y) works on or over), or None (the table or nothing)."""
        if not self.names:  # no fixture to find: no ray casts at every primitive's start
            return None
        geom = np.zeros(1, dtype=np.int32)
        start, down = np.array([x, y, 1.0]), np.array([0.0, 0.0, -1.0])
        exclude = -1
        for _ in range(len(self._objects) + 1):
            distance = mujoco.mj_ray(self.model, self.data, start, down, WORLD_GROUP, 1, exclude, geom)
            if distance < 0:
                return None
            body = int(self.model.geom_bodyid[geom[0]])
            if body not in self._objects:
                return self.names.get(int(geom[0]))
            start, exclude = start + distance * down, body  # an object: look on below it
        return None


def _primitive_bounds(geom_type: int, size: Sequence[float]) -> tuple[np.ndarray, float, np.ndarray] | None:
    """MuJoCo's (size, bounding-sphere radius, local bounding-box half sizes) of a box, sphere, capsule,
    cylinder or ellipsoid of ``size`` (metres: as many as the type uses), or None for another type or a bad
    size."""
    values = np.asarray(size, dtype=float).ravel()
    used = {
        int(mujoco.mjtGeom.mjGEOM_BOX): 3,
        int(mujoco.mjtGeom.mjGEOM_ELLIPSOID): 3,
        int(mujoco.mjtGeom.mjGEOM_SPHERE): 1,
        int(mujoco.mjtGeom.mjGEOM_CAPSULE): 2,
        int(mujoco.mjtGeom.mjGEOM_CYLINDER): 2,
    }.get(geom_type)
    if used is None or values.size != used or not np.all(np.isfinite(values) & (values > 0)):
        return None
    full = np.zeros(3)
    full[:used] = values
    if used == 3:
        return full, float(np.linalg.norm(full) if geom_type == mujoco.mjtGeom.mjGEOM_BOX else full.max()), full
    radius = full[0]
    if used == 1:
        return full, radius, np.full(3, radius)
    half = full[1]
    if geom_type == mujoco.mjtGeom.mjGEOM_CAPSULE:
        return full, radius + half, np.array([radius, radius, radius + half])
    return full, float(np.hypot(radius, half)), np.array([radius, radius, half])
