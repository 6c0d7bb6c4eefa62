"""VPG-style top-down orthographic heightmaps from RGB-D images.

Grid layout (matches the overhead camera's view, robot at the bottom):
row ``i`` covers world x = ``x_max - (i + 0.5) * resolution`` and column ``j``
covers world y = ``y_max - (j + 0.5) * resolution``.  Heights are metres above
``z_min`` (the table top by default), at least 0; points above ``z_max`` are left out.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any

import numpy as np

from panda_grasp_env.perception.camera import CameraModel
from panda_grasp_env.perception.images import check_depth, check_pair, check_points

#: VPG's workspace: a 0.448 m square in front of the robot (224 x 224 cells at 2 mm).
DEFAULT_BOUNDS = ((0.276, 0.724), (-0.224, 0.224), (0.0, 0.3))
#: Row and column offsets of a cell's 3 x 3 neighbourhood (itself included), for filling holes.
NEIGHBOUR_ROWS, NEIGHBOUR_COLS = np.repeat([-1, 0, 1], 3), np.tile([-1, 0, 1], 3)


@dataclass(frozen=True)
class HeightmapGrid:
    """A world-aligned grid over ``bounds`` ((x_min, x_max), (y_min, y_max), (z_min, z_max)) metres."""

    bounds: tuple[tuple[float, float], tuple[float, float], tuple[float, float]] = DEFAULT_BOUNDS
    resolution: float = 0.002  # metres per cell

    def __post_init__(self) -> None:
        b = np.asarray(self.bounds, dtype=float)
        if b.shape != (3, 2) or not np.all(np.isfinite(b)) or np.any(b[:, 1] <= b[:, 0]):
            raise ValueError(
                f"heightmap bounds must be ((x0, x1), (y0, y1), (z0, z1)) with x0 < x1 ..., got {self.bounds}"
            )
        if not np.isfinite(self.resolution) or self.resolution <= 0:
            raise ValueError(f"heightmap resolution must be a positive number of metres, got {self.resolution}")

    @classmethod
    def of_layout(cls, layout: dict) -> HeightmapGrid:
        """The grid of a ``pixel`` action layout (``info["action_layout"]``: ``heightmap_bounds``,
        ``heightmap_resolution``)."""
        bounds = tuple(tuple(pair) for pair in layout["heightmap_bounds"])
        return cls(bounds, layout["heightmap_resolution"])  # type: ignore[arg-type]

    def layout(self) -> dict[str, Any]:
        """The grid as ``of_layout`` reads it back: ``heightmap_bounds`` and ``heightmap_resolution``, JSON-able."""
        return {"heightmap_bounds": [list(map(float, b)) for b in self.bounds], "heightmap_resolution": self.resolution}

    @property
    def shape(self) -> tuple[int, int]:
        """(rows, columns)."""
        (x0, x1), (y0, y1), _ = self.bounds
        return int(round((x1 - x0) / self.resolution)), int(round((y1 - y0) / self.resolution))

    def cell_centres(self, rows: np.ndarray, cols: np.ndarray) -> np.ndarray:
        """World (x, y) of cell centres, shape (..., 2)."""
        (_, x1), (_, y1), _ = self.bounds
        return np.stack(
            [x1 - (np.asarray(rows) + 0.5) * self.resolution, y1 - (np.asarray(cols) + 0.5) * self.resolution], -1
        )

    def cell_position(self, xy: np.ndarray) -> np.ndarray:
        """Fractional (row, column) of world points (..., 2), the inverse of ``cell_centres``: a cell's centre
        is at whole numbers; may lie outside the grid."""
        (_, x1), (_, y1), _ = self.bounds
        xy = np.asarray(xy, dtype=float)
        return np.stack([(x1 - xy[..., 0]) / self.resolution - 0.5, (y1 - xy[..., 1]) / self.resolution - 0.5], -1)

    def world_to_cell(self, xy: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """(row, column) indices of world points (..., 2); may lie outside the grid."""
        (_, x1), (_, y1), _ = self.bounds
        xy = np.asarray(xy, dtype=float)
        return (
            np.floor((x1 - xy[..., 0]) / self.resolution).astype(int),
            np.floor((y1 - xy[..., 1]) / self.resolution).astype(int),
        )


def heightmap_from_points(
    grid: HeightmapGrid, points: np.ndarray, colours: np.ndarray | None = None, fill_holes: bool = True
) -> tuple[np.ndarray, np.ndarray | None]:
    """Project world points (N, 3) (and their colours (N, 3) uint8) onto the grid, keeping the highest per cell.

    Returns heights (rows, cols) float32 metres above ``z_min`` and colours
    (rows, cols, 3) uint8 (or None).  Cells no point fell in are 0 (table) and
    black; with ``fill_holes`` single-cell gaps between sampled points are
    filled from their highest neighbour (the camera samples ~1 point per 2 mm
    cell, so aliasing leaves such gaps).
    """
    rows_n, cols_n = grid.shape
    (_, _), (_, _), (z0, z1) = grid.bounds
    points = check_points(points)
    rows, cols = grid.world_to_cell(points[:, :2])
    keep = (rows >= 0) & (rows < rows_n) & (cols >= 0) & (cols < cols_n) & np.isfinite(points[:, 2])
    keep &= points[:, 2] <= z1
    rows, cols = rows[keep], cols[keep]
    heights = np.clip(points[keep, 2] - z0, 0.0, z1 - z0)
    flat = rows * cols_n + cols
    # Sort by cell, then by height within a cell; the last entry of each cell is its highest point.
    order = np.lexsort((heights, flat))
    flat, heights = flat[order], heights[order]
    last = np.ones(len(flat), dtype=bool)
    last[:-1] = flat[1:] != flat[:-1]
    height_map = np.zeros(rows_n * cols_n, dtype=np.float32)
    height_map[flat[last]] = heights[last]
    observed = np.zeros(rows_n * cols_n, dtype=bool)
    observed[flat[last]] = True
    colour_map = None
    if colours is not None:
        colours = np.asarray(colours)
        if colours.shape[-1:] != (3,) or colours.size != points.size:
            raise ValueError(f"colours must be one RGB triple per point ({len(points)}), got shape {colours.shape}")
        colours = colours.reshape(-1, 3)[keep][order]
        colour_map = np.zeros((rows_n * cols_n, 3), dtype=np.uint8)
        colour_map[flat[last]] = colours[last]
        colour_map = colour_map.reshape(rows_n, cols_n, 3)
    height_map = height_map.reshape(rows_n, cols_n)
    if fill_holes:
        holes = ~observed.reshape(rows_n, cols_n)
        # Each hole takes the highest cell of its 3 x 3 neighbourhood (in padded coordinates) and that same
        # cell's colour (a per-channel maximum would mix a red and a green neighbour into yellow).
        rows, cols = np.nonzero(holes)
        neighbour_rows = rows[:, None] + 1 + NEIGHBOUR_ROWS
        neighbour_cols = cols[:, None] + 1 + NEIGHBOUR_COLS
        padded = np.pad(height_map, 1, constant_values=-np.inf)
        best = padded[neighbour_rows, neighbour_cols].argmax(axis=1)
        source = np.arange(len(rows)), best
        source_rows, source_cols = neighbour_rows[source], neighbour_cols[source]
        height_map[rows, cols] = padded[source_rows, source_cols]
        if colour_map is not None:
            colour_map[rows, cols] = np.pad(colour_map, ((1, 1), (1, 1), (0, 0)))[source_rows, source_cols]
    return height_map, colour_map


def heightmap_from_rgbd(
    grid: HeightmapGrid, camera: CameraModel, rgb: np.ndarray | None, depth: np.ndarray
) -> tuple[np.ndarray, np.ndarray | None]:
    """Heightmap (and colour map) from one camera's depth (H, W) metres and optional RGB (H, W, 3).

    Only the part of the image that sees the grid's box is back-projected.  ``ValueError`` if the images
    are not the camera's size, RGB is not uint8, or depth has no finite pixel.
    """
    rgb, depth = (None, check_depth(depth)) if rgb is None else check_pair(rgb, depth)
    if depth.shape != (camera.height, camera.width):
        raise ValueError(f"depth {depth.shape} is not the camera's image size ({camera.height}, {camera.width})")
    corners = np.array([[x, y, z] for x in grid.bounds[0] for y in grid.bounds[1] for z in grid.bounds[2]])
    window = camera.window_around(corners)
    points = camera.depth_to_world_points(depth, window)
    colours = None if rgb is None else rgb[window].reshape(-1, 3)
    return heightmap_from_points(grid, points.reshape(-1, 3), colours)


def heightmap_of_boxes(
    grid: HeightmapGrid, centres: np.ndarray, half_extents: np.ndarray, yaws: np.ndarray
) -> np.ndarray:
    """The heightmap ((rows, cols) float32, metres above the grid's floor, clipped to its height) of upright boxes
    turned ``yaws`` (n,) radians about z, with ``centres`` (n, 3) world metres and ``half_extents`` (n, 3): a
    cell takes the highest top whose footprint holds the cell's centre, 0 where none does."""
    rows, cols = grid.shape
    cells = grid.cell_centres(*np.meshgrid(np.arange(rows), np.arange(cols), indexing="ij"))
    heights = np.zeros((rows, cols), dtype=np.float32)
    floor, ceiling = grid.bounds[2]
    for centre, half, yaw in zip(np.asarray(centres, float), np.asarray(half_extents, float), np.asarray(yaws, float)):
        offset = cells - centre[:2]
        along = offset[..., 0] * np.cos(yaw) + offset[..., 1] * np.sin(yaw)
        across = -offset[..., 0] * np.sin(yaw) + offset[..., 1] * np.cos(yaw)
        inside = (np.abs(along) <= half[0]) & (np.abs(across) <= half[1])
        top = np.clip(centre[2] + half[2] - floor, 0.0, ceiling - floor)
        heights[inside] = np.maximum(heights[inside], top)
    return heights
