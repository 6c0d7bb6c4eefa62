"""Rotations and number checks every layer uses (world frame, radians; quaternions (w, x, y, z) as MuJoCo's)."""

from __future__ import annotations

from typing import Any

import numpy as np
from scipy.spatial.transform import Rotation


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
    """Quaternion (w, x, y, z) of a rotation by ``yaw`` about world z."""
    return Rotation.from_euler("z", yaw).as_quat(scalar_first=True)


def rotation_about(axis: np.ndarray, angle: float) -> np.ndarray:
    """(3, 3) rotation by ``angle`` about ``axis`` (any length but zero)."""
    axis = np.asarray(axis, dtype=float)
    return Rotation.from_rotvec(axis / np.linalg.norm(axis) * angle).as_matrix()


def lying_quaternion(yaw: float) -> np.ndarray:
    """Quaternion (w, x, y, z) of an object turned a quarter about its x axis (a capsule or cylinder on its
    side, its axis horizontal), then by ``yaw`` about world z."""
    return (Rotation.from_euler("z", yaw) * Rotation.from_euler("x", np.pi / 2)).as_quat(scalar_first=True)
