"""Model-free parallel-jaw grasp detection on a point cloud (the role GPD plays in the source study).

1. Objects: points more than 5 mm above the table plane, voxel-downsampled
   (3 mm), with surface normals from the covariance of their nearest
   neighbours, grouped into clusters (objects) by proximity.
2. Candidates: at sampled seed points, for closing-axis headings across and
   along each object's principal axes plus evenly spaced ones, the fingers'
   closing region is the object's slab under the pads; the hand is centred on
   the slab's extent, and the candidate's width is that extent.
3. Rejection: wider than the gripper opens; fingers (as they come down, open)
   or palm intersecting any point of any object; fingertips below the table.
4. Score: antipodality of the contact normals, how well the slab fills the
   pads, a grasp through the object's centre, and the source study's
   selection criteria -- approach facing the robot (here: from above) and
   closing axis across the object's principal axis of least inertia (so the
   fingers close on its short side), not too close to the table.

Output: candidates ranked by score, each a 6-DOF grasp-site pose (position,
rotation with x = closing axis, z = approach direction), the opening width
it needs and its score.  World frame, metres, radians.
"""

from __future__ import annotations

from dataclasses import dataclass

import cv2
import numpy as np
from scipy.sparse import coo_matrix
from scipy.sparse.csgraph import connected_components
from scipy.spatial import cKDTree

from panda_grasp_env.geometry import top_down_rotation
from panda_grasp_env.perception.camera import CameraModel
from panda_grasp_env.perception.images import check_points
from panda_grasp_env.perception.segmentation import Plane, fit_plane_ransac, region_points

#: Where grasps are looked for (world metres): the table in front of the robot, up to 30 cm high.
#: It keeps the robot's own body (at home, above and behind it) out of the cloud.
REGION_OF_INTEREST = np.array([[0.25, 0.75], [-0.35, 0.35], [-0.05, 0.3]])


#: Candidates whose fingers pass further than this (metres) beside the object's centre are rejected.
MAX_OFF_CENTRE = 0.02


@dataclass(frozen=True)
class GripperGeometry:
    """The Panda hand as grasp detection sees it, metres (grasp site = centre between the finger pads)."""

    #: Widest object the fingers can close on (the 73 mm opening less a margin).
    max_width: float = 0.066
    #: The fingers when open stand this far apart (inner faces).
    open_width: float = 0.073
    finger_thickness: float = 0.012
    #: Finger width across the closing axis (the pad is 17 mm).
    finger_width: float = 0.02
    #: Fingertips reach this far below the grasp site; the palm starts this far above it.
    fingertip_below: float = 0.015
    palm_above: float = 0.045
    #: Half length (along the closing axis) and half width of the palm and hand body.
    palm_half_length: float = 0.1
    palm_half_width: float = 0.03
    #: The grasp site goes this far below an object's top (nearer the centre of mass of tall objects; the
    #: palm still clears the top), but never below ``min_height`` above the table.
    grasp_depth: float = 0.035
    min_height: float = 0.02


@dataclass(frozen=True)
class GraspCandidate:
    """A ranked grasp: grasp-site ``position`` (3,), ``rotation`` (3, 3) (x closing, z approach), opening ``width``."""

    position: np.ndarray
    rotation: np.ndarray
    width: float
    score: float
    #: Heading of the closing axis about world z.
    yaw: float
    #: Index of the object (point cluster) it grasps.
    object_index: int


def prepare_cloud(
    points: np.ndarray,
    table: Plane,
    region: np.ndarray = REGION_OF_INTEREST,
    voxel: float = 0.003,
    neighbours: int = 10,
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Object points above the table inside ``region`` ((x0, x1), (y0, y1), (z0, z1)), voxel-downsampled:
    points (M, 3), upward-ish unit normals (M, 3), cluster label per point (M,)."""
    points = check_points(points)
    points = points[np.isfinite(points).all(axis=1)]
    inside = np.all((points >= region[:, 0]) & (points <= region[:, 1]), axis=1)
    points = points[inside & (table.height(points) > 0.005)]
    if len(points) == 0:
        return np.zeros((0, 3)), np.zeros((0, 3)), np.zeros(0, dtype=int)
    cells = np.floor((points - points.min(axis=0)) / voxel).astype(np.int64)
    span = cells.max(axis=0) + 1
    _, first = np.unique((cells[:, 0] * span[1] + cells[:, 1]) * span[2] + cells[:, 2], return_index=True)
    points = points[np.sort(first)]
    tree = cKDTree(points)
    k = min(neighbours, len(points))
    _, index = tree.query(points, k=k)
    index = index.reshape(len(points), k)
    local = points[index] - points[index].mean(axis=1, keepdims=True)
    covariance = np.einsum("nki,nkj->nij", local, local)
    normals = np.linalg.eigh(covariance)[1][:, :, 0]  # smallest eigenvalue's vector
    normals *= np.where(normals[:, 2:3] < 0, -1.0, 1.0)  # seen from above: normals point up or sideways
    pairs = tree.query_pairs(2.5 * voxel, output_type="ndarray")
    graph = coo_matrix((np.ones(len(pairs)), (pairs[:, 0], pairs[:, 1])), shape=(len(points), len(points)))
    labels = connected_components(graph, directed=False)[1]
    return points, normals, _merge_slivers(points, labels)


def _merge_slivers(points: np.ndarray, labels: np.ndarray, small: int = 60, reach: float = 0.015) -> np.ndarray:
    """Attach small clusters to the big cluster nearest in the table plane (within ``reach`` metres).

    A camera sees an object's side walls at a grazing angle, as sparse rows that fall apart from its
    top surface; left alone they look like thin objects beside it, and grasps aimed at them pinch
    a corner.
    """
    sizes = np.bincount(labels)
    big = sizes[labels] >= small
    if big.all() or not big.any():
        return labels
    distance, nearest = cKDTree(points[big, :2]).query(points[~big, :2], distance_upper_bound=reach)
    attach = np.isfinite(distance)
    merged = labels.copy()
    merged[np.flatnonzero(~big)[attach]] = labels[big][nearest[attach]]
    return merged


def detect_grasps(
    points: np.ndarray,
    table: Plane,
    rng: np.random.Generator,
    gripper: GripperGeometry | None = None,
    seeds: int = 30,
    headings: int = 4,
    min_cluster: int = 15,
    region: np.ndarray = REGION_OF_INTEREST,
) -> list[GraspCandidate]:
    """Ranked grasp candidates (best first) on a world-frame point cloud (N, 3) inside ``region``;
    empty if nothing stands on the table there."""
    gripper = gripper or GripperGeometry()
    cloud, normals, labels = prepare_cloud(points, table, region)
    if len(cloud) == 0:
        return []
    counts = np.bincount(labels)
    usable = np.flatnonzero(counts[labels] >= min_cluster)
    if len(usable) == 0:
        return []
    table_z = -table.offset / table.normal[2]
    tree = cKDTree(cloud[:, :2])
    reach = np.hypot(gripper.palm_half_length, gripper.palm_half_width) + 0.01
    objects = {label: ObjectOutline.of(cloud[labels == label], headings) for label in np.unique(labels[usable])}
    # Seeds: the point nearest each object's centre (grasps through the centre of mass), then random ones.
    central = [
        int(
            np.flatnonzero(labels == label)[
                np.argmin(np.linalg.norm(cloud[labels == label, :2] - shape.centre, axis=1))
            ]
        )
        for label, shape in objects.items()
    ]
    random_seeds = rng.choice(usable, size=min(seeds, len(usable)), replace=False)
    candidates = []
    for seed in dict.fromkeys([*central, *random_seeds.tolist()]):
        outline = objects[labels[seed]]
        nearby = np.asarray(tree.query_ball_point(cloud[seed, :2], reach))
        for yaw in outline.headings:
            candidate = _evaluate(cloud, normals, labels, nearby, seed, yaw, gripper, table_z, outline)
            if candidate is not None:
                candidates.append(candidate)
    candidates.sort(key=lambda c: -c.score)
    return candidates


@dataclass(frozen=True)
class ObjectOutline:
    """What the top view says about one object's footprint (from its upper surface: the side wall a
    camera sees off-axis would pull the centre towards it)."""

    centre: np.ndarray
    #: Principal axis of least inertia (the long axis) in the table plane, and how elongated (0 round/square, 1 a line).
    long_axis: np.ndarray
    elongation: float
    #: Heading of the minimum-area rectangle's first side, and how box-like (0 a disc, 1 a rectangle).
    rectangle_heading: float
    rectangularity: float
    #: Closing-axis headings worth trying (radians, in [0, pi)).
    headings: np.ndarray

    @classmethod
    def of(cls, points: np.ndarray, even_headings: int) -> ObjectOutline:
        upper = points[points[:, 2] > points[:, 2].max() - 0.01, :2]
        centre = upper.mean(axis=0)
        eigenvalues, eigenvectors = np.linalg.eigh((upper - centre).T @ (upper - centre))
        long_axis = eigenvectors[:, 1]
        (_, (w, h), angle) = cv2.minAreaRect(upper.astype(np.float32))
        hull_area = cv2.contourArea(cv2.convexHull(upper.astype(np.float32)))
        rectangularity = float(np.clip((hull_area / max(w * h, 1e-9) - np.pi / 4) / (1 - np.pi / 4), 0.0, 1.0))
        rectangle = np.deg2rad(angle)
        long_heading = np.arctan2(long_axis[1], long_axis[0])
        headings = [rectangle, rectangle + np.pi / 2, long_heading, long_heading + np.pi / 2]
        headings += list(long_heading + np.pi * np.arange(even_headings) / even_headings)
        elongation = 1.0 - eigenvalues[0] / max(eigenvalues[1], 1e-12)
        return cls(
            centre,
            long_axis,
            float(elongation),
            float(rectangle),
            rectangularity,
            np.unique(np.round(np.mod(headings, np.pi), 3)),
        )


def _evaluate(
    cloud: np.ndarray,
    normals: np.ndarray,
    labels: np.ndarray,
    nearby: np.ndarray,
    seed: int,
    yaw: float,
    gripper: GripperGeometry,
    table_z: float,
    outline: ObjectOutline,
) -> GraspCandidate | None:
    closing = np.array([np.cos(yaw), np.sin(yaw)])
    lateral = np.array([-closing[1], closing[0]])
    offsets = cloud[nearby, :2] - cloud[seed, :2]
    u, v, z = offsets @ closing, offsets @ lateral, cloud[nearby, 2]
    own = labels[nearby] == labels[seed]
    in_slab = own & (np.abs(v) < gripper.finger_width / 2)
    if np.count_nonzero(in_slab) < 3:
        return None
    top = z[in_slab].max()
    grasp_z = max(top - gripper.grasp_depth, table_z + gripper.min_height)
    gripped = in_slab & (z >= grasp_z - gripper.fingertip_below)
    if np.count_nonzero(gripped) < 3:
        return None
    low, high = u[gripped].min(), u[gripped].max()
    width = high - low
    if width > gripper.max_width or width < 0.004:
        return None
    centre_u = (low + high) / 2
    # Fingers come down open: nothing may stand in their boxes (any object), down to the fingertips.
    outer = gripper.open_width / 2 + gripper.finger_thickness
    du = np.abs(u - centre_u)
    fingers = (du > gripper.open_width / 2) & (du < outer) & (np.abs(v) < gripper.finger_width / 2 + 0.003)
    if np.any(fingers & (z > grasp_z - gripper.fingertip_below)):
        return None
    palm = (du < gripper.palm_half_length) & (np.abs(v) < gripper.palm_half_width) & (z > grasp_z + gripper.palm_above)
    if np.any(palm):
        return None
    # Score: antipodal contacts, filled pads, through the centre, across the long axis.
    ends = gripped & ((u < low + 0.004) | (u > high - 0.004))
    sides = np.sign(u[ends] - centre_u)
    contact_normals = normals[nearby[ends], :2] @ closing
    antipodal = float(np.mean(np.clip(contact_normals * sides, 0.0, 1.0))) if np.any(ends) else 0.0
    band = gripped & (np.abs(z - grasp_z) < 0.012)
    fill = min(1.0, np.count_nonzero(band) / 12.0)
    position_xy = cloud[seed, :2] + centre_u * closing
    off_centre = abs((position_xy - outline.centre) @ lateral)
    if off_centre > MAX_OFF_CENTRE:  # e.g. across a cube's corner: the pads would only pinch an edge
        return None
    through_centre = 1.0 - off_centre / MAX_OFF_CENTRE
    across_long = 1.0 - outline.elongation * abs(closing @ outline.long_axis)
    # Box-like objects: close on a pair of faces, not across corners.
    face_aligned = 1.0 - outline.rectangularity * (1.0 - np.cos(4 * (yaw - outline.rectangle_heading))) / 2
    score = 0.2 * antipodal + 0.15 * fill + 0.25 * through_centre + 0.2 * across_long + 0.2 * face_aligned
    position = np.array([*position_xy, grasp_z])
    return GraspCandidate(position, top_down_rotation(yaw), float(width), float(score), float(yaw), int(labels[seed]))


def detect_grasps_rgbd(
    depth: np.ndarray,
    camera: CameraModel,
    rng: np.random.Generator,
    gripper: GripperGeometry | None = None,
    region: np.ndarray = REGION_OF_INTEREST,
) -> list[GraspCandidate]:
    """The whole pipeline on one depth image (H, W) metres: back-project the part of the image that
    sees ``region``, fit the table plane (RANSAC), detect grasps.  Empty when nothing stands there."""
    points = region_points(depth, camera, region).reshape(-1, 3)
    points = points[np.isfinite(points).all(axis=1)]
    if len(points) < 3:
        return []
    table, _ = fit_plane_ransac(points, rng)
    return detect_grasps(points, table, rng, gripper, region=region)
