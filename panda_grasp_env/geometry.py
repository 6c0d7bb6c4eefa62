"""Rotations and number checks every layer uses (world frame, radians; quaternions (w, x, y, z) as MuJoCo's)."""

from __future__ import annotations

import math
from typing import Any

import numpy as np
from scipy.spatial.transform import Rotation


def is_count(value: Any) -> bool:
    """Whether ``value`` is a whole number (a Python or NumPy int, not a bool: ``True`` is no count of 1)."""
    return isinstance(value, (int, np.integer)) and not isinstance(value, (bool, np.bool_))


def is_number(value: Any) -> bool:
    """Whether ``value`` is a finite real number (an int or float, not a bool): test it before comparing."""
    return (
        isinstance(value, (int, float, np.integer, np.floating))
        and not isinstance(value, (bool, np.bool_))
        and bool(np.isfinite(value))
    )


def top_down_rotation(yaw: float) -> np.ndarray:
    """(3, 3) rotation of a hand pointing straight down whose closing axis has heading ``yaw``: Rz(yaw) Rx(pi).

    Written out rather than through ``Rotation``: the controller calls it every control step."""
    c, s = np.cos(yaw), np.sin(yaw)
    return np.array([[c, s, 0.0], [s, -c, 0.0], [0.0, 0.0, -1.0]])


def yaw_quaternion(yaw: float) -> np.ndarray:
    """Quaternion (w, x, y, z) of a rotation by ``yaw`` about world z (written out: every reset calls it)."""
    half = 0.5 * float(yaw)
    return np.array([math.cos(half), 0.0, 0.0, math.sin(half)])


def rotation_about(axis: np.ndarray, angle: float) -> np.ndarray:
    """(3, 3) rotation by ``angle`` about ``axis`` (any length but zero)."""
    axis = np.asarray(axis, dtype=float)
    return Rotation.from_rotvec(axis / np.linalg.norm(axis) * angle).as_matrix()


def lying_quaternion(yaw: float) -> np.ndarray:
    """Quaternion (w, x, y, z) of an object turned a quarter about its x axis (a capsule or cylinder on its
    side, its axis horizontal), then by ``yaw`` about world z: Rz(yaw) Rx(pi/2).

    Written out: ``Rotation``'s product differs in the last bit for a third of the yaws, and a heap of
    objects dropped from poses one bit apart settles differently (every clutter figure was measured on these)."""
    half_c, half_s = np.cos(yaw / 2), np.sin(yaw / 2)
    quarter_c, quarter_s = np.cos(np.pi / 4), np.sin(np.pi / 4)
    return np.array([half_c * quarter_c, half_c * quarter_s, half_s * quarter_s, half_s * quarter_c])


#: Shapes ``half_extent_along`` knows exactly (MuJoCo geom types by name).
EXACT_SHAPES = ("box", "sphere", "capsule", "cylinder")


def half_extent_along(kind: str, size: np.ndarray, rotation: np.ndarray, axis: np.ndarray) -> float:
    """Half the extent (metres) along the world unit vector ``axis`` of a shape of MuJoCo geom ``size``
    (half-extents; radius; radius and half-height) rotated by ``rotation`` (3, 3), for ``EXACT_SHAPES``."""
    local = rotation.T @ axis  # the axis in the shape's frame
    if kind == "box":
        return float(np.abs(local) @ size)
    if kind == "sphere":
        return float(size[0])
    if kind == "capsule":
        return float(size[0] + abs(local[2]) * size[1])
    if kind == "cylinder":
        return float(abs(local[2]) * size[1] + size[0] * np.sqrt(max(0.0, 1.0 - local[2] ** 2)))
    raise ValueError(f"unknown shape {kind!r}; valid: {list(EXACT_SHAPES)}")
