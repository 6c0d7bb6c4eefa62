"""Pinhole model of a MuJoCo camera: intrinsics, extrinsics, back-projection and projection.

Frames: the *camera frame* here is OpenCV's (x right, y down, z forward along
the optical axis), not MuJoCo's (x right, y up, looking along -z).  Depth is
metres along the optical axis (what MuJoCo's depth render gives).  Pixel
(u, v) = (column, row) indices; a pixel's centre sits at integer coordinates.
"""

from __future__ import annotations

import functools
from dataclasses import dataclass
from typing import TYPE_CHECKING

import numpy as np

if TYPE_CHECKING:  # importing mujoco here would fix its GL backend before MUJOCO_GL is chosen
    import mujoco

#: MuJoCo camera axes -> OpenCV camera axes (flip y and z).
_MJ_TO_CV = np.diag([1.0, -1.0, -1.0])


@dataclass(frozen=True)
class CameraModel:
    """A calibrated pinhole camera: ``K`` (3, 3) intrinsics and its pose in the world.

    ``rotation`` (3, 3) maps camera-frame vectors to the world frame and
    ``position`` (3,) is the optical centre in the world, metres.
    """

    width: int
    height: int
    K: np.ndarray
    rotation: np.ndarray
    position: np.ndarray

    @classmethod
    def from_mujoco(
        cls, model: mujoco.MjModel, data: mujoco.MjData, camera: str | int, width: int, height: int
    ) -> CameraModel:
        """The model of MuJoCo camera ``camera`` rendering ``width`` x ``height`` images, posed as in ``data``.

        ``data`` must have had ``mj_forward``/``mj_step`` run (camera poses are computed there).
        """
        cam_id = model.camera(camera).id
        fovy = np.deg2rad(model.cam_fovy[cam_id])
        focal = 0.5 * height / np.tan(fovy / 2)
        K = np.array([[focal, 0.0, (width - 1) / 2], [0.0, focal, (height - 1) / 2], [0.0, 0.0, 1.0]])
        rotation = data.cam_xmat[cam_id].reshape(3, 3) @ _MJ_TO_CV
        return cls(width, height, K, rotation, data.cam_xpos[cam_id].copy())

    def pixel_rays(self) -> np.ndarray:
        """Camera-frame direction (H, W, 3) of every pixel, scaled so z = 1 (cached per intrinsics; read-only)."""
        return _pixel_rays(self.width, self.height, *self.K[[0, 1, 0, 1], [0, 1, 2, 2]])

    def depth_to_camera_points(self, depth: np.ndarray, window: tuple[slice, slice] | None = None) -> np.ndarray:
        """Back-project a depth image (H, W) metres to camera-frame points (H, W, 3).

        ``window`` (rows, columns) back-projects only that part of the image (``depth`` is still whole).
        """
        depth = np.asarray(depth)
        if depth.shape != (self.height, self.width):
            raise ValueError(f"depth image has shape {depth.shape}, camera is {(self.height, self.width)}")
        window = window or (slice(None), slice(None))
        return self.pixel_rays()[window] * depth[window][..., None]

    def depth_to_world_points(self, depth: np.ndarray, window: tuple[slice, slice] | None = None) -> np.ndarray:
        """Back-project a depth image (H, W) metres to world-frame points (H, W, 3) (or of a ``window``)."""
        return self.depth_to_camera_points(depth, window) @ self.rotation.T + self.position

    def window_around(self, corners: np.ndarray, margin: int = 2) -> tuple[slice, slice]:
        """The image rows and columns that can see world points inside the box spanned by ``corners`` (N, 3)."""
        uv, depth = self.world_to_pixel(corners)
        if np.any(depth <= 0):
            return slice(None), slice(None)  # part of the box is behind the camera: keep everything
        (u0, v0), (u1, v1) = np.floor(uv.min(axis=0)) - margin, np.ceil(uv.max(axis=0)) + margin
        rows = slice(int(np.clip(v0, 0, self.height)), int(np.clip(v1 + 1, 0, self.height)))
        cols = slice(int(np.clip(u0, 0, self.width)), int(np.clip(u1 + 1, 0, self.width)))
        return rows, cols

    def world_to_pixel(self, points: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Project world points (..., 3) to pixel coordinates (..., 2) as (u, v), and their depth (...)."""
        camera_points = (np.asarray(points, dtype=float) - self.position) @ self.rotation
        depth = camera_points[..., 2]
        uv = camera_points[..., :2] / depth[..., None] * np.diag(self.K)[:2] + self.K[:2, 2]
        return uv, depth


@functools.lru_cache(maxsize=16)
def _pixel_rays(width: int, height: int, fx: float, fy: float, cx: float, cy: float) -> np.ndarray:
    u, v = np.meshgrid(np.arange(width), np.arange(height))
    rays = np.stack([(u - cx) / fx, (v - cy) / fy, np.ones((height, width))], axis=-1)
    rays.flags.writeable = False
    return rays
