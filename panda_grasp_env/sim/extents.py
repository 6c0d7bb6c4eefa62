"""How far bodies and geoms reach along a world direction, as they stand now: metres, world frame.

Exact for boxes, spheres, capsules, cylinders and meshes (their vertices); bounding spheres for other geoms.
A body's extent covers its collision geoms only.
"""

from __future__ import annotations

from collections.abc import Sequence

import mujoco
import numpy as np

from panda_grasp_env.geometry import half_extent_along

#: MuJoCo geom types ``half_extent_along`` knows exactly, by its names.
_EXACT_TYPES = {
    int(mujoco.mjtGeom.mjGEOM_BOX): "box",
    int(mujoco.mjtGeom.mjGEOM_SPHERE): "sphere",
    int(mujoco.mjtGeom.mjGEOM_CAPSULE): "capsule",
    int(mujoco.mjtGeom.mjGEOM_CYLINDER): "cylinder",
}


def geom_extent_along(model: mujoco.MjModel, data: mujoco.MjData, geom: int, axis: np.ndarray) -> tuple[float, float]:
    """Lowest and highest coordinate of a geom along the world unit vector ``axis``, metres (exact for boxes,
    spheres, capsules, cylinders and meshes; bounding spheres otherwise)."""
    kind = _EXACT_TYPES.get(int(model.geom_type[geom]))
    if int(model.geom_type[geom]) == int(mujoco.mjtGeom.mjGEOM_MESH):
        mesh = model.geom_dataid[geom]
        start, count = model.mesh_vertadr[mesh], model.mesh_vertnum[mesh]
        heights = model.mesh_vert[start : start + count] @ (data.geom_xmat[geom].reshape(3, 3).T @ axis)
        centre = float(data.geom_xpos[geom] @ axis)
        return centre + float(heights.min()), centre + float(heights.max())
    if kind is None:
        half = float(model.geom_rbound[geom])
    else:
        half = half_extent_along(kind, model.geom_size[geom], data.geom_xmat[geom].reshape(3, 3), axis)
    centre = float(data.geom_xpos[geom] @ axis)
    return centre - half, centre + half


def body_extent_along(
    model: mujoco.MjModel, data: mujoco.MjData, body_id: int, axis: np.ndarray | Sequence[float]
) -> tuple[float, float]:
    """Lowest and highest coordinate of a body's collision geoms along the world unit vector ``axis``, metres
    (see ``geom_extent_along``)."""
    axis = np.asarray(axis, dtype=float)
    lowest, highest = np.inf, -np.inf
    start, count = model.body_geomadr[body_id], model.body_geomnum[body_id]
    for g in range(start, start + count):
        if model.geom_contype[g] or model.geom_conaffinity[g]:  # else visual only
            low, high = geom_extent_along(model, data, g, axis)
            lowest, highest = min(lowest, low), max(highest, high)
    return lowest, highest


def body_vertical_extent(model: mujoco.MjModel, data: mujoco.MjData, body_id: int) -> tuple[float, float]:
    """Lowest and highest world z of a body's collision geoms, metres (see ``body_extent_along``)."""
    return body_extent_along(model, data, body_id, (0.0, 0.0, 1.0))


def body_bottom_height(model: mujoco.MjModel, data: mujoco.MjData, body_id: int) -> float:
    """Lowest world z of a body's collision geoms, metres (see ``body_vertical_extent``)."""
    return body_vertical_extent(model, data, body_id)[0]
