"""Segmentation: coloured blocks by HSV thresholds, unknown objects by height above a RANSAC table plane.

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

from panda_grasp_env.perception.images import check_points, check_rgb

#: Hue half-window (OpenCV units, 0-179) around each colour's hue.
HUE_WINDOW = 10
#: Minimum saturation and value (0-255) of a block pixel (side faces facing away from the light are dark, V ~ 20).
MIN_SATURATION = 100
MIN_VALUE = 12
#: Connected components smaller than this many pixels are dropped (noise, slivers).
MIN_COMPONENT = 12


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
