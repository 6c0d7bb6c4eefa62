"""Block pose estimation from RGB-D views (the pose estimator's role in the grasp loop), and tower detection.

For each colour: the masked pixels of every view are back-projected to world
points; a first guess comes from the highest face's minimum-area rectangle;
then the cube's pose (x, y, z, yaw) is fitted to all its points by robust
least squares on the cube's signed distance (every visible point lies on the
surface).  Points from several faces and cameras -- the overhead camera sees
top faces, the front camera the sides of blocks hidden under a tower's top --
pin the pose down; noise averages out instead of moving extreme points.

World frame, metres, radians; yaw is the heading of the block's x axis modulo
the cube's 90 degree symmetry, in [-pi/4, pi/4).
"""

from __future__ import annotations

from dataclasses import dataclass

import cv2
import numpy as np
from scipy.optimize import least_squares

from panda_grasp_env.perception.camera import CameraModel
from panda_grasp_env.perception.images import check_pair
from panda_grasp_env.perception.segmentation import colour_masks

#: Fewest points a block needs to be reported.
MIN_POINTS = 30
#: Robust-loss scale of the surface fit, metres (about the depth noise at 1 m).
FIT_SCALE = 0.003


@dataclass(frozen=True)
class View:
    """One camera's RGB (H, W, 3) uint8 and depth (H, W) metres (NaN = missing), and its model."""

    rgb: np.ndarray
    depth: np.ndarray
    camera: CameraModel


@dataclass(frozen=True)
class BlockPose:
    """An estimated cube pose: centre (3,) world metres, yaw radians in [-pi/4, pi/4)."""

    name: str
    position: np.ndarray
    yaw: float
    n_points: int
    #: RMS distance of the block's points from the fitted cube's surface, metres.
    residual: float


def wrap_quarter(angle: float) -> float:
    """Angle modulo 90 degrees, in [-pi/4, pi/4)."""
    return float((angle + np.pi / 4) % (np.pi / 2) - np.pi / 4)


def cube_surface_distance(points: np.ndarray, centre: np.ndarray, yaw: float, half: float) -> np.ndarray:
    """Signed distance (N,) of world points from the surface of a cube (half size ``half``) at ``centre``, ``yaw``."""
    c, s = np.cos(yaw), np.sin(yaw)
    offset = points - centre
    local = np.stack([c * offset[:, 0] + s * offset[:, 1], -s * offset[:, 0] + c * offset[:, 1], offset[:, 2]], axis=1)
    q = np.abs(local) - half
    outside = np.linalg.norm(np.maximum(q, 0.0), axis=1)
    inside = np.minimum(q.max(axis=1), 0.0)
    return outside + inside


def initial_guess(points: np.ndarray, rays: np.ndarray, block_size: float) -> np.ndarray:
    """(x, y, z, yaw) from the highest face: minimum-area rectangle of the points within 1 cm of the top."""
    top = np.percentile(points[:, 2], 95)
    face = points[points[:, 2] > top - 0.01, :2].astype(np.float32)
    (cx, cy), (w, h), angle = cv2.minAreaRect(face)
    centre = np.array([cx, cy])
    if min(w, h) < 0.6 * block_size:
        # Only a sliver of the top is seen (the upper edge of a side face): the centre lies half a
        # block behind it, on the side away from the cameras.
        across = np.deg2rad(angle + (90.0 if w >= h else 0.0))
        direction = np.array([np.cos(across), np.sin(across)])
        away = np.sign(direction @ rays[:, :2].mean(axis=0)) or 1.0
        centre = centre + away * direction * block_size / 2
    return np.array([centre[0], centre[1], top - block_size / 2, np.deg2rad(angle)])


def fit_cube(points: np.ndarray, rays: np.ndarray, block_size: float) -> tuple[np.ndarray, float, float]:
    """Centre (3,), yaw and RMS surface distance of the cube of edge ``block_size`` best fitting ``points`` (N, 3).

    ``rays`` (N, 3) are the unit viewing directions (camera to point).  A face alone fits a cube on
    either side of it; the cameras saw the outside, so one residual keeps the centre behind the
    points as seen along their rays.
    """
    half = block_size / 2
    guess = initial_guess(points, rays, block_size)
    weight = np.sqrt(len(points))

    def residuals(params: np.ndarray) -> np.ndarray:
        depth_behind = float(np.mean(np.einsum("ij,ij->i", params[:3] - points, rays)))
        visibility = weight * min(0.0, depth_behind)
        return np.append(cube_surface_distance(points, params[:3], params[3], half), visibility)

    fit = least_squares(residuals, guess, loss="soft_l1", f_scale=FIT_SCALE, x_scale=[0.01, 0.01, 0.01, 0.1])
    rms = float(np.sqrt(np.mean(cube_surface_distance(points, fit.x[:3], fit.x[3], half) ** 2)))
    return fit.x[:3], wrap_quarter(fit.x[3]), rms


def block_points(
    views: list[View], colours: dict[str, tuple[float, float, float]]
) -> dict[str, tuple[np.ndarray, np.ndarray]]:
    """World points (N, 3) of each colour's pixels over all views (missing depth skipped), and their
    unit viewing rays (N, 3)."""
    gathered: dict[str, list[tuple[np.ndarray, np.ndarray]]] = {name: [] for name in colours}
    for view in views:
        rgb, depth = check_pair(view.rgb, view.depth)
        world = view.camera.depth_to_world_points(depth)
        for name, mask in colour_masks(rgb, colours).items():
            selected = world[mask]
            selected = selected[np.isfinite(selected).all(axis=1)]
            rays = selected - view.camera.position
            gathered[name].append((selected, rays / np.linalg.norm(rays, axis=1, keepdims=True)))
    return {
        name: (np.concatenate([p for p, _ in parts]), np.concatenate([r for _, r in parts]))
        for name, parts in gathered.items()
    }


def estimate_block_poses(
    views: list[View], colours: dict[str, tuple[float, float, float]], block_size: float
) -> dict[str, BlockPose]:
    """Pose of every block seen in ``views``; colours with too few points are left out (never an exception)."""
    if not views:
        raise ValueError("estimate_block_poses needs at least one view")
    if not 0 < block_size < 0.5:
        raise ValueError(f"block_size must be in (0, 0.5) m, got {block_size}")
    poses = {}
    for name, (points, rays) in block_points(views, colours).items():
        if len(points) < MIN_POINTS:
            continue
        centre, yaw, rms = fit_cube(points, rays, block_size)
        poses[name] = BlockPose(name, centre, yaw, len(points), rms)
    return poses


def detect_towers(positions: dict[str, np.ndarray], block_size: float) -> list[list[str]]:
    """Stacks of blocks (name -> centre), each bottom-up: a block is on another when one block size
    (+-25 %) above it and within half a block horizontally.  Single blocks are towers of one."""
    ordered = sorted(positions, key=lambda name: positions[name][2])
    below: dict[str, str] = {}
    for upper in ordered:
        for lower in ordered:
            dz = positions[upper][2] - positions[lower][2]
            near = np.linalg.norm(positions[upper][:2] - positions[lower][:2]) < block_size / 2
            if near and abs(dz - block_size) < block_size / 4:
                below[upper] = lower
                break
    towers = []
    for name in ordered:
        if name in below:
            continue
        tower, current = [name], name
        while True:
            above = [name for name, under in below.items() if under == current]
            if not above:
                break
            current = above[0]
            tower.append(current)
        towers.append(tower)
    return towers
