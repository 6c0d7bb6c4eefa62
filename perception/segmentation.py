"""Segmentation: coloured blocks by HSV thresholds, unknown objects by height above a RANSAC table plane, and
packed objects one by one by their top surfaces in a depth image.

Colour segmentation keys on hue and saturation, which shading barely changes
(a side face in shadow is darker, not differently coloured), and ignores
brightness above a floor, so the same thresholds hold for lit top faces and
dim side faces.  The grey table and the grey-blue robot are far below the
saturation floor.
"""

from __future__ import annotations

from dataclasses import dataclass

import cv2
import numpy as np
from scipy import ndimage

from panda_grasp_env.perception.camera import CameraModel
from panda_grasp_env.perception.images import check_depth, check_points, check_rgb

#: Hue half-window (OpenCV units, 0-179) around each colour's hue.
HUE_WINDOW = 10
#: Minimum saturation and value (0-255) of a block pixel (side faces facing away from the light are dark, V ~ 20).
MIN_SATURATION = 100
MIN_VALUE = 12
#: Connected components smaller than this many pixels are dropped (noise, slivers).
MIN_COMPONENT = 12
#: ``object_tops``: a pixel lies on a top surface when it is at most ``TOP_STEP`` (metres) below the median
#: height of its 5 x 5 pixel neighbourhood.  The depth noise (about 2 mm at 1 m) stays within it; the gap between
#: two packed objects (a pixel or two wide, seen down to a side wall 1-2 cm below the tops) and the rim of the
#: lower of two neighbours of different heights do not.
TOP_STEP = 0.006
#: ``object_tops``: where the camera sees a gap only in part (it narrows below a pixel where objects turned
#: towards each other), the tops on either side stay joined by bridges; eroding the tops by ``CORE_RADIUS``
#: (metres) cuts bridges up to twice as wide, and each remaining core of at least ``MIN_CORE_AREA`` (square metres)
#: is one object.  Top pixels go to the nearest core within ``2 * CORE_RADIUS``; a top left without a core (an
#: object narrower than the erosion) of at least ``MIN_CORE_AREA`` is an object of its own.
CORE_RADIUS = 0.012
MIN_CORE_AREA = 1e-4


@dataclass(frozen=True)
class ColourRange:
    """HSV thresholds of one colour (OpenCV: hue 0-179, saturation and value 0-255)."""

    hue: int
    window: int = HUE_WINDOW
    min_saturation: int = MIN_SATURATION
    min_value: int = MIN_VALUE

    @classmethod
    def from_rgb(cls, rgb: tuple[float, float, float]) -> ColourRange:
        """Thresholds around the hue of an (r, g, b) colour in 0-1."""
        pixel = np.uint8([[np.clip(np.asarray(rgb) * 255, 0, 255)]])
        return cls(int(cv2.cvtColor(pixel, cv2.COLOR_RGB2HSV)[0, 0, 0]))

    def mask(self, hsv: np.ndarray) -> np.ndarray:
        """Boolean mask of the pixels of an HSV image in this range (hue wraps around at 180)."""
        low, high = self.hue - self.window, self.hue + self.window
        bright = (hsv[..., 1] >= self.min_saturation) & (hsv[..., 2] >= self.min_value)
        hue = hsv[..., 0].astype(np.int16)
        in_hue = (hue >= low) & (hue <= high)
        if low < 0:
            in_hue |= hue >= 180 + low
        if high > 179:
            in_hue |= hue <= high - 180
        return bright & in_hue


def colour_masks(rgb: np.ndarray, colours: dict[str, tuple[float, float, float]]) -> dict[str, np.ndarray]:
    """Per-colour boolean masks (H, W) of an RGB image; ``colours`` maps names to (r, g, b) in 0-1."""
    hsv = cv2.cvtColor(check_rgb(rgb), cv2.COLOR_RGB2HSV)
    masks = {}
    for name, colour in colours.items():
        mask = ColourRange.from_rgb(colour).mask(hsv)
        masks[name] = drop_small_components(mask, MIN_COMPONENT)
    return masks


def drop_small_components(mask: np.ndarray, min_pixels: int) -> np.ndarray:
    """The mask without its 8-connected components smaller than ``min_pixels``."""
    count, labels, stats, _ = cv2.connectedComponentsWithStats(mask.astype(np.uint8), connectivity=8)
    keep = np.zeros(count, dtype=bool)
    keep[1:] = stats[1:, cv2.CC_STAT_AREA] >= min_pixels
    return keep[labels]


@dataclass(frozen=True)
class Plane:
    """The plane n . p + d = 0, with unit normal ``normal`` pointing up (+z side), metres."""

    normal: np.ndarray
    offset: float

    def height(self, points: np.ndarray) -> np.ndarray:
        """Signed distance of points (..., 3) above the plane, metres."""
        return points @ self.normal + self.offset


def fit_plane_ransac(
    points: np.ndarray, rng: np.random.Generator, threshold: float = 0.004, iterations: int = 100
) -> tuple[Plane, np.ndarray]:
    """The dominant plane of a point cloud (N, 3) by RANSAC, refined by least squares on its inliers.

    Returns the plane and the inlier mask.  ``ValueError`` with fewer than 3 finite points.
    """
    points = check_points(points)
    finite = np.isfinite(points).all(axis=1)
    candidates = points[finite]
    if len(candidates) < 3:
        raise ValueError(f"plane fit needs at least 3 finite points, got {len(candidates)}")
    sample_pool = candidates[rng.choice(len(candidates), min(len(candidates), 5000), replace=False)]
    best_count, best = -1, None
    for _ in range(iterations):
        a, b, c = sample_pool[rng.choice(len(sample_pool), 3, replace=False)]
        normal = np.cross(b - a, c - a)
        norm = np.linalg.norm(normal)
        if norm < 1e-9:
            continue
        normal /= norm
        count = int(np.sum(np.abs((sample_pool - a) @ normal) < threshold))
        if count > best_count:
            best_count, best = count, (normal, a)
    if best is None:
        raise ValueError("plane fit: all sampled point triples were collinear")
    normal, anchor = best
    inliers = candidates[np.abs((candidates - anchor) @ normal) < threshold]
    if len(inliers) > 20_000:  # a least-squares refit needs no more
        inliers = inliers[rng.choice(len(inliers), 20_000, replace=False)]
    centroid = inliers.mean(axis=0)
    normal = np.linalg.svd(inliers - centroid, full_matrices=False)[2][2]
    if normal[2] < 0:
        normal = -normal
    plane = Plane(normal, float(-normal @ centroid))
    mask = np.zeros(len(points), dtype=bool)
    mask[np.flatnonzero(finite)] = np.abs(plane.height(candidates)) < threshold
    return plane, mask


def foreground_mask(world_points: np.ndarray, plane: Plane, min_height: float = 0.005) -> np.ndarray:
    """Pixels (H, W) whose world point (H, W, 3) stands more than ``min_height`` above the plane."""
    heights = plane.height(world_points)
    return np.isfinite(heights) & (heights > min_height)


def region_points(depth: np.ndarray, camera: CameraModel, region: np.ndarray) -> np.ndarray:
    """World points (H', W', 3) metres of the part of a depth image (H, W) metres that can see ``region``
    ((x0, x1), (y0, y1), (z0, z1)) metres; NaN where the depth is missing or the point lies outside ``region``."""
    depth = check_depth(depth)
    corners = np.array([[x, y, z] for x in region[0] for y in region[1] for z in region[2]])
    points = camera.depth_to_world_points(depth, camera.window_around(corners))
    inside = np.all((points >= region[:, 0]) & (points <= region[:, 1]), axis=-1)  # False where NaN
    return np.where(inside[..., None], points, np.nan)


def object_tops(points: np.ndarray, table: Plane, camera: CameraModel) -> list[np.ndarray]:
    """The objects standing on ``table`` in a point image (H, W, 3) (``region_points`` of ``camera``'s depth
    image), one by one even where they stand packed: the world points (N, 3), metres, of each object's top
    surface, split at the gaps the camera sees between them (``TOP_STEP``, ``CORE_RADIUS``).

    Depth alone: objects touching with no gap a pixel wide come out as one.  Image-space work, so that the
    gaps keep their pixels (a heightmap cell mixes a gap's pixel with the tops beside it).
    """
    heights = table.height(points)
    above = foreground_mask(points, table)
    heights = np.where(above, heights, 0.0).astype(np.float32)
    top = above & (heights > cv2.medianBlur(heights, 5) - TOP_STEP)
    # A pixel the noise dropped (or pushed low) inside a top surface is top again when nearly all around it is.
    around = cv2.filter2D(top.astype(np.float32), -1, np.ones((3, 3), np.float32), borderType=cv2.BORDER_CONSTANT)
    top |= around >= 7
    pixel = abs(float(table.height(camera.position))) / float(camera.K[0, 0])  # metres per pixel on the table
    radius = max(1, round(CORE_RADIUS / pixel))
    min_pixels = MIN_CORE_AREA / pixel**2
    disc = cv2.getStructuringElement(cv2.MORPH_ELLIPSE, (2 * radius + 1, 2 * radius + 1))
    count, cores = cv2.connectedComponents(cv2.erode(top.astype(np.uint8), disc), connectivity=4)
    small = np.bincount(cores.ravel(), minlength=count) < min_pixels
    small[0] = False
    cores[small[cores]] = 0
    if cores.any():
        distance, (rows, cols) = ndimage.distance_transform_edt(cores == 0, return_indices=True)
        labels = np.where(top & (distance <= 2 * radius), cores[rows, cols], 0)
    else:
        labels = np.zeros_like(cores)
    count, rest = cv2.connectedComponents((top & (labels == 0)).astype(np.uint8), connectivity=4)
    sizes = np.bincount(rest.ravel(), minlength=count)
    seen = np.isfinite(points).all(axis=-1)  # not the pixels filled in above
    objects = [points[(labels == label) & seen] for label in np.unique(labels[labels > 0])]
    objects += [points[(rest == label) & seen] for label in range(1, count) if sizes[label] >= min_pixels]
    return objects
