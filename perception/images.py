"""Input checks shared by the perception functions: bad images raise ``ValueError`` naming the problem."""

from __future__ import annotations

import numpy as np


def check_rgb(rgb: np.ndarray, name: str = "rgb") -> np.ndarray:
    """An (H, W, 3) uint8 image, or ``ValueError``."""
    rgb = np.asarray(rgb)
    if rgb.ndim != 3 or rgb.shape[2] != 3 or rgb.shape[0] == 0 or rgb.shape[1] == 0:
        raise ValueError(f"{name} must have shape (H, W, 3) with H, W > 0, got {rgb.shape}")
    if rgb.dtype != np.uint8:
        raise ValueError(f"{name} must be uint8, got {rgb.dtype}")
    return rgb


def check_depth(depth: np.ndarray, name: str = "depth") -> np.ndarray:
    """An (H, W) (or (H, W, 1)) float depth image in metres with some finite pixels, or ``ValueError``."""
    depth = np.asarray(depth)
    if depth.ndim == 3 and depth.shape[2] == 1:
        depth = depth[..., 0]
    if depth.ndim != 2 or depth.size == 0:
        raise ValueError(f"{name} must have shape (H, W) with H, W > 0, got {depth.shape}")
    if depth.dtype.kind != "f":
        raise ValueError(f"{name} must be a float array of metres, got {depth.dtype}")
    if not np.isfinite(depth).any():
        raise ValueError(f"{name} has no finite pixel (all NaN or inf)")
    return depth


def check_pair(rgb: np.ndarray, depth: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Checked RGB and depth images of the same size."""
    rgb, depth = check_rgb(rgb), check_depth(depth)
    if rgb.shape[:2] != depth.shape:
        raise ValueError(f"rgb {rgb.shape[:2]} and depth {depth.shape} images differ in size")
    return rgb, depth


def check_points(points: np.ndarray, name: str = "points") -> np.ndarray:
    """Points (..., 3) -- a cloud (N, 3) or a point image (H, W, 3) -- as an (N, 3) float array, or ``ValueError``."""
    points = np.asarray(points, dtype=float)
    if points.ndim < 1 or points.shape[-1] != 3:
        raise ValueError(f"{name} must have shape (..., 3) (x, y, z in metres), got {points.shape}")
    return points.reshape(-1, 3)
