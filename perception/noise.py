"""Seeded sensor noise for rendered RGB-D images, Kinect-like.

Depth: axial Gaussian noise whose standard deviation grows with distance,
sigma(z) = 1.2 mm + 1.9 mm * (z - 0.4 m)^2 (Nguyen, Izadi and Lovell, 2012,
measured on a Kinect v1), and dropouts: missing depth (NaN) at depth
discontinuities and at a small random fraction of pixels.  RGB: Gaussian intensity noise.  Missing depth is NaN;
every consumer in ``perception`` ignores non-finite depth.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from panda_grasp_env.perception.images import check_depth, check_rgb


@dataclass(frozen=True)
class DepthNoise:
    """Kinect-like depth noise.  Lengths in metres."""

    base_sigma: float = 0.0012
    quadratic_sigma: float = 0.0019
    reference_depth: float = 0.4
    #: Pixels whose depth differs from a neighbour's by more than this lie on an edge.
    edge_jump: float = 0.01
    #: Probability that an edge pixel has no depth.
    edge_dropout: float = 0.5
    #: Probability that any pixel has no depth.
    random_dropout: float = 0.002

    def sigma(self, depth: np.ndarray) -> np.ndarray:
        """Axial standard deviation (metres) at ``depth`` (metres)."""
        return self.base_sigma + self.quadratic_sigma * (depth - self.reference_depth) ** 2

    def apply(self, depth: np.ndarray, rng: np.random.Generator) -> np.ndarray:
        """A noisy copy of a depth image (H, W) in metres; missing pixels are NaN."""
        depth = check_depth(depth).astype(np.float64)
        noisy = depth + rng.standard_normal(depth.shape) * self.sigma(np.nan_to_num(depth))
        # Depth discontinuities: the largest jump to a 4-neighbour.
        padded = np.pad(np.nan_to_num(depth), 1, mode="edge")
        jump = np.zeros_like(depth)
        for dr, dc in ((0, 1), (2, 1), (1, 0), (1, 2)):
            neighbour = padded[dr : dr + depth.shape[0], dc : dc + depth.shape[1]]
            jump = np.maximum(jump, np.abs(neighbour - np.nan_to_num(depth)))
        edges = jump > self.edge_jump
        missing = (edges & (rng.random(depth.shape) < self.edge_dropout)) | (
            rng.random(depth.shape) < self.random_dropout
        )
        noisy[missing | ~np.isfinite(depth)] = np.nan
        return noisy.astype(np.float32)


@dataclass(frozen=True)
class RGBNoise:
    """Gaussian intensity noise, in 8-bit levels."""

    sigma: float = 3.0

    def apply(self, rgb: np.ndarray, rng: np.random.Generator) -> np.ndarray:
        rgb = check_rgb(rgb)
        noisy = rgb.astype(np.float32) + rng.standard_normal(rgb.shape).astype(np.float32) * self.sigma
        return np.clip(noisy, 0, 255).astype(np.uint8)
