"""Pinhole model of a MuJoCo camera: intrinsics, extrinsics, back-projection and projection.

Frames: the *camera frame* here is OpenCV's (x right, y down, z forward along
the optical axis), not MuJoCo's (x right, y up, looking along -z).  Depth is
metres along the optical axis (what MuJoCo's depth render gives).  Pixel
(u, v) = (column, row) indices; a pixel's centre sits at integer coordinates.
"""

from __future__ import annotations

from dataclasses import dataclass

import mujoco
import numpy as np

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
        """Camera-frame direction (H, W, 3) of every pixel, scaled so z = 1."""
        u, v = np.meshgrid(np.arange(self.width), np.arange(self.height))
        x = (u - self.K[0, 2]) / self.K[0, 0]
        y = (v - self.K[1, 2]) / self.K[1, 1]
        return np.stack([x, y, np.ones_like(x)], axis=-1)

    def depth_to_camera_points(self, depth: np.ndarray) -> np.ndarray:
        """Back-project a depth image (H, W) metres to camera-frame points (H, W, 3)."""
        depth = np.asarray(depth)
        if depth.shape != (self.height, self.width):
            raise ValueError(f"depth image has shape {depth.shape}, camera is {(self.height, self.width)}")
        return self.pixel_rays() * depth[..., None]

    def depth_to_world_points(self, depth: np.ndarray) -> np.ndarray:
        """Back-project a depth image (H, W) metres to world-frame points (H, W, 3)."""
        return self.depth_to_camera_points(depth) @ self.rotation.T + self.position

    def world_to_pixel(self, points: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Project world points (..., 3) to pixel coordinates (..., 2) as (u, v), and their depth (...)."""
        camera_points = (np.asarray(points, dtype=float) - self.position) @ self.rotation
        depth = camera_points[..., 2]
        uv = camera_points[..., :2] / depth[..., None] * np.diag(self.K)[:2] + self.K[:2, 2]
        return uv, depth
