"""Block pose estimation from RGB-D views (the pose estimator's role in the grasp loop), and tower detection.

Two ways to gather each block's points, one fit:

* ``estimate_block_poses`` (blocks of distinct, known colours): a block's
  points are the pixels of its colour in every view, back-projected to the
  world; the colour names the block.
* ``estimate_block_poses_from_depth`` (no colour read; blocks may all look
  alike): the points above the table split into groups that touch in (x, y),
  each group into levels one block size high (blocks rest flat on the table
  or on each other), and a level into blocks where its top is wider than one
  block.  The blocks are anonymous; ``follow_blocks`` names them after the
  blocks of an earlier estimate they lie nearest.

Then, per block: a first guess from the highest face's minimum-area rectangle,
and the cube's pose (x, y, z, yaw; from depth alone z is its level's height)
fitted to all its points by robust least squares on the cube's signed
distance (every visible point lies on the surface).  Points from several faces and cameras -- the overhead camera sees
top faces, the front camera the sides of blocks hidden under a tower's top --
pin the pose down; noise averages out instead of moving extreme points.

World frame, metres, radians; yaw is the heading of the block's x axis modulo
the cube's 90 degree symmetry, in [-pi/4, pi/4).
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from dataclasses import dataclass

import cv2
import numpy as np
from scipy.optimize import least_squares, linear_sum_assignment

from panda_grasp_env.perception.camera import CameraModel
from panda_grasp_env.perception.images import check_depth, check_pair
from panda_grasp_env.perception.segmentation import colour_masks

#: Fewest points a block needs to be reported.
MIN_POINTS = 30
#: Robust-loss scale of the surface fit, metres (about the depth noise at 1 m).
FIT_SCALE = 0.003
#: Depth points less than this above the table belong to it (about four standard deviations of the depth
#: noise at 1 m, 1.9 mm), metres.
TABLE_CLEARANCE = 0.008
#: Half the height of the band around a boundary between two levels of blocks, whose points could lie on either
#: block, and how far depth noise may move a top face's points from its block's top, metres.
LEVEL_MARGIN = 0.005
#: Side of the (x, y) grid cells on which points are joined into groups that touch, metres.
GROUP_CELL = 0.004


@dataclass(frozen=True)
class View:
    """One camera's RGB (H, W, 3) uint8 and depth (H, W) metres (NaN = missing), and its model."""

    rgb: np.ndarray
    depth: np.ndarray
    camera: CameraModel


@dataclass(frozen=True)
class BlockRegion:
    """Where ``estimate_block_poses_from_depth`` looks for blocks: world x and y bounds, the table top's height
    and the highest block top, metres.  The defaults: the table in front of the robot's base (which, with the
    arm, stands behind x = 0.2), up to 0.41 m: a tower of eight 5 cm blocks stands 0.397 m, and a block held
    at the home pose hangs down to 0.422 m (its bottom; the fingertips stay above 0.43 m)."""

    x: tuple[float, float] = (0.2, 1.0)
    y: tuple[float, float] = (-0.6, 0.6)
    table: float = 0.0
    top: float = 0.41


@dataclass(frozen=True)
class BlockPose:
    """An estimated cube pose: centre (3,) world metres, yaw radians in [-pi/4, pi/4).

    ``name``: the block's colour name (``estimate_block_poses``), or its place in the list of an anonymous
    estimate (``seen_<i>``, ``estimate_block_poses_from_depth``: no identity across estimates)."""

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


def fit_cube(
    points: np.ndarray, rays: np.ndarray, block_size: float, height: float | None = None
) -> tuple[np.ndarray, float, float]:
    """Centre (3,), yaw and RMS surface distance of the cube of edge ``block_size`` best fitting ``points`` (N, 3).

    ``rays`` (N, 3) are the unit viewing directions (camera to point).  A face alone fits a cube on
    either side of it; the cameras saw the outside, so one residual keeps the centre behind the
    points as seen along their rays.  ``height``: the centre's z where it is known (a block resting flat at a
    known level), else z is fitted too.
    """
    half = block_size / 2
    guess = initial_guess(points, rays, block_size)
    free = np.array([True, True, height is None, True])  # x, y, z, yaw
    if height is not None:
        guess[2] = height
    weight = np.sqrt(len(points))

    def pose(params: np.ndarray) -> np.ndarray:
        full = guess.copy()
        full[free] = params
        return full

    def residuals(params: np.ndarray) -> np.ndarray:
        x = pose(params)
        depth_behind = float(np.mean(np.einsum("ij,ij->i", x[:3] - points, rays)))
        visibility = weight * min(0.0, depth_behind)
        return np.append(cube_surface_distance(points, x[:3], x[3], half), visibility)

    scale = np.array([0.01, 0.01, 0.01, 0.1])[free]
    fit = pose(least_squares(residuals, guess[free], loss="soft_l1", f_scale=FIT_SCALE, x_scale=scale).x)
    rms = float(np.sqrt(np.mean(cube_surface_distance(points, fit[:3], fit[3], half) ** 2)))
    return fit[:3], wrap_quarter(fit[3]), rms


@dataclass(frozen=True)
class BlockPoints:
    """One block's world points (N, 3), their unit viewing rays (N, 3), and its centre's height (world z, metres)
    where that is known (None: fitted)."""

    points: np.ndarray
    rays: np.ndarray
    height: float | None = None


def block_points(views: list[View], colours: dict[str, tuple[float, float, float]]) -> dict[str, BlockPoints]:
    """World points (N, 3) of each colour's pixels over all views (missing depth skipped), with their
    unit viewing rays (N, 3)."""
    gathered: dict[str, list[tuple[np.ndarray, np.ndarray]]] = {name: [] for name in colours}
    for view in views:
        rgb, depth = check_pair(view.rgb, view.depth)
        world = view.camera.depth_to_world_points(depth)
        for name, mask in colour_masks(rgb, colours).items():
            selected = world[mask]
            selected = selected[np.isfinite(selected).all(axis=1)]
            gathered[name].append((selected, unit_rays(selected, view.camera)))
    return {
        name: BlockPoints(np.concatenate([p for p, _ in parts]), np.concatenate([r for _, r in parts]))
        for name, parts in gathered.items()
    }


def unit_rays(points: np.ndarray, camera: CameraModel) -> np.ndarray:
    """Unit viewing directions (N, 3), from ``camera``'s optical centre to world ``points`` (N, 3)."""
    rays = points - camera.position
    return rays / np.linalg.norm(rays, axis=1, keepdims=True)


def fit_blocks(point_sets: Mapping[str, BlockPoints], block_size: float) -> dict[str, BlockPose]:
    """The cube fitted to each named block's points; blocks with fewer than ``MIN_POINTS`` points are left out."""
    poses = {}
    for name, block in point_sets.items():
        if len(block.points) < MIN_POINTS:
            continue
        centre, yaw, rms = fit_cube(block.points, block.rays, block_size, block.height)
        poses[name] = BlockPose(name, centre, yaw, len(block.points), rms)
    return poses


def check_estimate_inputs(views: list[View], block_size: float) -> None:
    """``ValueError`` unless there is a view and ``block_size`` is a plausible edge length (metres)."""
    if not views:
        raise ValueError("block pose estimation needs at least one view")
    if not 0 < block_size < 0.5:
        raise ValueError(f"block_size must be in (0, 0.5) m, got {block_size}")


def estimate_block_poses(
    views: list[View], colours: dict[str, tuple[float, float, float]], block_size: float
) -> dict[str, BlockPose]:
    """Pose of every block seen in ``views``; colours with too few points are left out (never an exception)."""
    check_estimate_inputs(views, block_size)
    return fit_blocks(block_points(views, colours), block_size)


def points_in_region(views: list[View], region: BlockRegion) -> tuple[np.ndarray, np.ndarray]:
    """World points (N, 3) of every view's depth inside ``region`` and more than ``TABLE_CLEARANCE`` above its
    table (missing depth skipped), and their unit viewing rays (N, 3).  Colour is not read."""
    points, rays = [], []
    for view in views:
        world = view.camera.depth_to_world_points(check_depth(view.depth)).reshape(-1, 3)
        with np.errstate(invalid="ignore"):  # NaN depth: compared False, dropped
            inside = (
                (world[:, 0] >= region.x[0])
                & (world[:, 0] <= region.x[1])
                & (world[:, 1] >= region.y[0])
                & (world[:, 1] <= region.y[1])
                & (world[:, 2] > region.table + TABLE_CLEARANCE)
                & (world[:, 2] <= region.top)
            )
        points.append(world[inside])
        rays.append(unit_rays(world[inside], view.camera))
    return np.concatenate(points), np.concatenate(rays)


def touching_groups(points: np.ndarray) -> list[np.ndarray]:
    """Indices into ``points`` (N, 3) of each group whose (x, y) cells (``GROUP_CELL``) touch, gaps of one
    cell closed: a block's top face and the sides the cameras see of it, or a tower, or blocks side by side."""
    cells = np.floor(points[:, :2] / GROUP_CELL).astype(np.int64)
    cells -= cells.min(axis=0) - 1  # a free border, so closing does not reach past the grid
    grid = np.zeros(cells.max(axis=0) + 2, dtype=np.uint8)
    grid[cells[:, 0], cells[:, 1]] = 1
    grid = cv2.morphologyEx(grid, cv2.MORPH_CLOSE, np.ones((3, 3), np.uint8))
    _, labels = cv2.connectedComponents(grid, connectivity=8)
    point_labels = labels[cells[:, 0], cells[:, 1]]
    order = np.argsort(point_labels, kind="stable")
    bounds = np.flatnonzero(np.diff(point_labels[order])) + 1
    return np.split(order, bounds)


def split_side_by_side(points: np.ndarray, block_size: float) -> list[np.ndarray]:
    """Indices into one level's points (N, 3) of each block in it: the level's top band (within a fifth of a
    block of its highest point: top faces, or the upper edges of the sides of a block whose top is hidden) has
    a minimum-area rectangle; one that spans several block sizes along a side holds blocks side by side, and the
    points go to the block-sized cell of the rectangle they lie over."""
    band = points[points[:, 2] > points[:, 2].max() - block_size / 5, :2].astype(np.float32)
    (cx, cy), (width, height), angle = cv2.minAreaRect(band)
    counts = np.maximum(1, np.rint(np.array([width, height]) / block_size)).astype(int)
    if counts.prod() == 1:
        return [np.arange(len(points))]
    turn = np.deg2rad(angle)
    axes = np.array([[np.cos(turn), np.sin(turn)], [-np.sin(turn), np.cos(turn)]])  # rows: the sides' directions
    local = (points[:, :2] - [cx, cy]) @ axes.T + np.array([width, height]) / 2
    index = np.clip(np.floor(local / np.array([width, height]) * counts), 0, counts - 1).astype(int)
    cell = index[:, 0] * counts[1] + index[:, 1]
    return [np.flatnonzero(cell == c) for c in range(counts.prod())]


def depth_point_sets(points: np.ndarray, block_size: float, table: float) -> list[tuple[np.ndarray, float]]:
    """Indices into ``points`` (N, 3, above the table at height ``table``) of each block's points, and the height
    of the block's centre (world z, metres): groups that touch in (x, y), split into levels of ``block_size``
    from the table up, and a level into blocks side by side.

    A group's top face counts to the level below it, however far noise lifts it.  Points within
    ``LEVEL_MARGIN`` of a boundary between two of a group's levels are left out: they could lie on either block
    (a lower block's top meets the upper one's sides there).  The levels' centres divide the height of the
    group's top face (its points' median; the block size where no top face is seen) evenly: resting blocks sink
    into each other a little (0.4 mm a contact in this simulation), so a tower is a little lower than its
    blocks' sizes add up to."""
    sets = []
    for group in touching_groups(points):
        heights = points[group, 2] - table
        top = int(max(0, np.floor((np.percentile(heights, 99) - LEVEL_MARGIN) / block_size)))
        levels = np.clip(np.floor((heights - LEVEL_MARGIN) / block_size), 0, top).astype(int)
        boundary = np.rint(heights / block_size)
        between = (boundary >= 1) & (boundary <= top) & (np.abs(heights - boundary * block_size) < LEVEL_MARGIN)
        top_face = np.abs(heights - (top + 1) * block_size) < LEVEL_MARGIN
        level_height = np.median(heights[top_face]) / (top + 1) if top_face.any() else block_size
        for level in range(top + 1):
            members = group[(levels == level) & ~between]
            centre = table + (level + 0.5) * level_height
            if len(members):
                sets += [(members[part], centre) for part in split_side_by_side(points[members], block_size)]
    return sets


def estimate_block_poses_from_depth(
    views: list[View], block_size: float, region: BlockRegion = BlockRegion()
) -> list[BlockPose]:
    """Pose of every cube of edge ``block_size`` (metres) seen in the views' depth inside ``region``, resting
    flat on its table or on other cubes (so its centre's height is its level's, ``depth_point_sets``: only x,
    y and yaw are fitted).  Colour is not read.  The blocks are anonymous (``seen_<i>``; ``follow_blocks``
    names them); an empty table gives ``[]``."""
    check_estimate_inputs(views, block_size)
    points, rays = points_in_region(views, region)
    if len(points) < MIN_POINTS:
        return []
    blocks = {
        f"seen_{i}": BlockPoints(points[indices], rays[indices], height)
        for i, (indices, height) in enumerate(depth_point_sets(points, block_size, region.table))
    }
    poses = fit_blocks(blocks, block_size).values()
    return [BlockPose(f"seen_{i}", p.position, p.yaw, p.n_points, p.residual) for i, p in enumerate(poses)]


def follow_blocks(known: Mapping[str, np.ndarray], seen: Sequence[BlockPose]) -> list[str | None]:
    """For each ``seen`` block, the name of the ``known`` block (name -> centre (3,), world metres) it continues,
    or None: the one-to-one pairing of least total centre distance, so a block keeps its name while it is the
    nearest to where that name was.  With more blocks seen than known, those left out of the pairing go unnamed."""
    names = list(known)
    if not names or not seen:
        return [None] * len(seen)
    distances = np.linalg.norm(
        np.array([b.position for b in seen])[:, None, :] - np.array([known[n] for n in names])[None], axis=2
    )
    rows, columns = linear_sum_assignment(distances)
    paired: list[str | None] = [None] * len(seen)
    for row, column in zip(rows, columns):
        paired[row] = names[column]
    return paired


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
