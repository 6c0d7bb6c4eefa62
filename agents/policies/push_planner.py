"""Planning grasps and pushes on objects seen from above: which grasp clears every neighbour, and which push
frees the most objects when none does (the packed scenes of ``PandaGraspAdversarial-v0``).

``PushPlanner`` works on a ``PackedScene``: per object its ``columns`` seen from above.  The planned grasp agent
makes the scene from one depth image (``camera_scene``); the push-aware oracle from the true shapes
(``footprint``).  World frame, metres, radians.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass
from typing import Any

import numpy as np

from panda_grasp_env.geometry import top_down_rotation
from panda_grasp_env.perception.grasps import REGION_OF_INTEREST, GraspCandidate, GripperGeometry, ObjectOutline
from panda_grasp_env.perception.heightmap import DEFAULT_BOUNDS
from panda_grasp_env.perception.pose import View
from panda_grasp_env.perception.segmentation import fit_plane_ransac, object_tops, region_points

#: Spacing of the points an object's volume is sampled with for finger clearance checks, metres.
SAMPLE_SPACING = 0.004
#: Clearance kept around the open fingers, the pusher and the palm, metres.
CLEARANCE = 0.002
#: Headings tried for grasps and pushes, radians (grasps: 8 over a half turn; pushes: 8 over a full turn).
GRASP_HEADINGS = np.arange(8) * np.pi / 8
PUSH_HEADINGS = np.arange(8) * np.pi / 4
#: Push stroke height above the table (metres); the closed fingers seen from above: half their width across
#: the stroke and half their depth along it (metres, the Panda's finger links); the gap left between them and
#: the object at the start (metres); the sideways shifts of the stroke off an object's centre line tried.
PUSH_HEIGHT, PUSHER_HALF_WIDTH, PUSHER_HALF_DEPTH, PUSH_GAP = 0.015, 0.031, 0.02, 0.01
PUSH_SHIFTS = (-0.025, 0.0, 0.025)
#: A clump (several objects seen as one: too wide for the hand at every heading) is also pushed with the fingers
#: over only its outermost ``CLUMP_EDGE`` metres on either side, to take one object off it.
CLUMP_EDGE = 0.03
#: Where objects count as in play for the push planner (world x, y bounds, metres): VPG's workspace.
PLAY_REGION = np.asarray(DEFAULT_BOUNDS[:2])


def _near(points: np.ndarray, others: np.ndarray) -> bool:
    """Whether any of ``points`` (N, 2) lies within ``SAMPLE_SPACING`` of any of ``others`` (M, 2), metres."""
    low, high = others.min(axis=0) - SAMPLE_SPACING, others.max(axis=0) + SAMPLE_SPACING
    candidates = points[np.all((points >= low) & (points <= high), axis=1)]
    if not len(candidates):
        return False
    return bool(np.min(np.linalg.norm(candidates[:, None] - others[None], axis=2)) < SAMPLE_SPACING)


def columns(points: np.ndarray) -> np.ndarray:
    """Points (N, 3) of one object, world metres, as seen from above: one column (x, y, highest z) per cell of a
    ``SAMPLE_SPACING`` grid they fall in, (M, 3)."""
    cells, inverse = np.unique(np.round(points[:, :2] / SAMPLE_SPACING).astype(int), axis=0, return_inverse=True)
    tops = np.full(len(cells), -np.inf)
    np.maximum.at(tops, inverse.ravel(), points[:, 2])
    return np.column_stack([cells * SAMPLE_SPACING, tops])


def footprint(model: Any, data: Any, body: int) -> np.ndarray:
    """``columns`` (N, 3) covering the first geom of ``body`` seen from above: world x, y and the top z of the
    geom over that point (metres), from its true pose and shape."""
    geom = int(model.body_geomadr[body])
    kind, size = int(model.geom_type[geom]), model.geom_size[geom]
    if kind == 6:  # box
        half = size
    elif kind == 2:  # sphere
        half = np.full(3, size[0])
    else:  # capsule (radius, half length), cylinder (radius, half height): axis along local z
        half = np.array([size[0], size[0], size[1] + (size[0] if kind == 3 else 0.0)])
    axes = [np.linspace(-h, h, max(2, int(np.ceil(2 * h / SAMPLE_SPACING)) + 1)) for h in half]
    local = np.stack(np.meshgrid(*axes, indexing="ij"), -1).reshape(-1, 3)
    if kind == 2:
        local = local[np.linalg.norm(local, axis=1) <= size[0] + 1e-9]
    elif kind == 5:
        local = local[np.hypot(local[:, 0], local[:, 1]) <= size[0] + 1e-9]
    elif kind == 3:
        beyond = np.clip(np.abs(local[:, 2]) - size[1], 0.0, None)
        local = local[np.hypot(np.hypot(local[:, 0], local[:, 1]), beyond) <= size[0] + 1e-9]
    return columns(local @ data.xmat[body].reshape(3, 3).T + data.xpos[body])


@dataclass(frozen=True)
class PackedScene:
    """The objects in play as the push planner sees them (world frame, metres, radians): per object (keyed by an
    index) its ``columns`` (N, 3), and the closing-axis headings along its faces, tried besides
    ``GRASP_HEADINGS``."""

    objects: dict[int, np.ndarray]
    face_headings: dict[int, tuple[float, ...]]


def camera_scene(view: View, rng: np.random.Generator) -> PackedScene:
    """The ``PackedScene`` one depth image shows (``View``: its depth and camera): the tops of the objects
    (``object_tops``, split at the gaps the camera sees between packed ones) whose centre lies in
    ``PLAY_REGION``, with the headings of their outline's sides and axes (``ObjectOutline``)."""
    points = region_points(view.depth, view.camera, REGION_OF_INTEREST)
    finite = np.isfinite(points).all(axis=-1)
    if np.count_nonzero(finite) < 3:
        return PackedScene({}, {})
    table, _ = fit_plane_ransac(points[finite], rng)
    objects, headings = {}, {}
    for index, top in enumerate(object_tops(points, table, view.camera)):
        centre = top[:, :2].mean(axis=0)
        if np.all((centre >= PLAY_REGION[:, 0]) & (centre <= PLAY_REGION[:, 1])):
            objects[index] = columns(top)
            headings[index] = tuple(ObjectOutline.of(top, 0).headings)
    return PackedScene(objects, headings)


@dataclass(frozen=True)
class PackedDecision:
    """What the push planner chose: a ``grasp`` (``clear`` when nothing is in the hand's way), or a push from
    world ``push_start`` (x, y) metres along heading ``push_heading`` radians (``grasp`` None); neither when the
    scene holds nothing that fits the hand and no push helps."""

    grasp: GraspCandidate | None = None
    clear: bool = False
    push_start: np.ndarray | None = None
    push_heading: float = 0.0


class PushPlanner:
    """Top-down grasps that clear every other object, and the push that frees most, planned on a ``PackedScene``:
    the true shapes for ``grasping.PackedGraspOracle``, the camera's object tops for ``grasping.PlannedGraspAgent``.

    Grasps: for each object, at each of ``GRASP_HEADINGS`` and its face headings, a top-down grasp through its
    centre (``grasp_depth`` below its top) whose width across the fingers fits the hand.  Clear: no column of
    another object inside either open finger's box, from the fingertips up, or under the palm.

    Pushes: for each object and each of ``PUSH_HEADINGS`` (and ``PUSH_SHIFTS`` sideways) the closed fingers start
    just behind it -- where they clear everything -- and push ``push_distance``; the object and whatever its
    sweep meets (transitively) are predicted to move along with it.  The push that leaves the most objects with
    a clear grasp (then: the least blocked grasp freest; then: moving the fewest; never one that moves an
    object out of ``PLAY_REGION``) is chosen, if it does better than the scene as it is.  ``push_distance``
    None: no pushes (the grasp-only oracle; action modes without them).

    Clumps: an object too wide for the hand at every heading is several objects the camera could not tell
    apart (touching, no gap seen).  The fingers are predicted to take along only the part of a clump in their
    band, leaving the rest, and clumps are also pushed at their edges (``CLUMP_EDGE``).  True shapes make none.
    """

    def __init__(self, push_distance: float | None, gripper: GripperGeometry | None = None) -> None:
        self.push_distance = push_distance
        self.gripper = gripper or GripperGeometry()

    def clumps(self, scene: PackedScene) -> set[int]:
        """The objects of ``scene`` too wide for the hand at every heading tried."""
        wide = set()
        for index, points in scene.objects.items():
            headings = np.array([*GRASP_HEADINGS, *scene.face_headings.get(index, ())])
            closing = np.stack([np.cos(headings), np.sin(headings)], axis=1)
            u = points[:, :2] @ closing.T
            if np.all(u.max(axis=0) - u.min(axis=0) > self.gripper.max_width):
                wide.add(index)
        return wide

    def grasps(self, scene: PackedScene) -> list[tuple[int, GraspCandidate]]:
        """(columns of other objects in the hand's way, candidate) for every fitting grasp, fewest first."""
        g = self.gripper
        ranked = []
        for index, points in scene.objects.items():
            others = np.concatenate([p for i, p in scene.objects.items() if i != index] or [np.zeros((0, 3))])
            centre, top = points[:, :2].mean(axis=0), points[:, 2].max()
            z = max(top - g.grasp_depth, g.min_height)
            for yaw in (*GRASP_HEADINGS, *scene.face_headings.get(index, ())):
                closing = np.array([np.cos(yaw), np.sin(yaw)])
                lateral = np.array([-closing[1], closing[0]])
                u = (points[:, :2] - centre) @ closing
                width = float(u.max() - u.min())
                if width > g.max_width:
                    continue
                du = np.abs((others[:, :2] - centre) @ closing)
                dv = np.abs((others[:, :2] - centre) @ lateral)
                fingers = (du > g.open_width / 2 - CLEARANCE) & (du < g.open_width / 2 + g.finger_thickness + CLEARANCE)
                fingers &= (dv < g.finger_width / 2 + CLEARANCE) & (others[:, 2] > z - g.fingertip_below)
                palm = (du < g.palm_half_length) & (dv < g.palm_half_width) & (others[:, 2] > z + g.palm_above)
                blocked = int(np.count_nonzero(fingers | palm))
                candidate = GraspCandidate(np.array([*centre, z]), top_down_rotation(yaw), width, -width, yaw, index)
                ranked.append((blocked, candidate))
        ranked.sort(key=lambda item: (item[0], item[1].width, item[1].object_index))
        return ranked

    def clearance(self, scene: PackedScene) -> tuple[int, int]:
        """(objects with at least one clear grasp, minus the columns in the way of the least blocked grasp)."""
        ranked = self.grasps(scene)
        return len({c.object_index for blocked, c in ranked if blocked == 0}), -(ranked[0][0] if ranked else 0)

    def push_outcome(
        self, scene: PackedScene, index: int, heading: float, shift: float, clumps: set[int]
    ) -> tuple | None:
        """(``clearance`` after, -objects moved, start xy) of a push along ``heading`` that starts just behind
        object ``index``, ``shift`` metres to the left of its centre line; None if the closed fingers cannot come
        down there or something would leave the play region.

        The closed fingers are a ``PUSHER_HALF_WIDTH`` x ``PUSHER_HALF_DEPTH`` box; every object whose
        footprint the box sweeps moves the full stroke less the start gap, and so does whatever those sweep
        on (transitively).  Of a clump (``clumps``: objects of ``scene`` too wide for the hand) the box sweeps,
        only the columns ahead in its band move."""
        objects, headings = dict(scene.objects), dict(scene.face_headings)
        direction = np.array([np.cos(heading), np.sin(heading)])
        lateral = np.array([-direction[1], direction[0]])
        points = objects[index]
        centre = points[:, :2].mean(axis=0)
        rear = float(((points[:, :2] - centre) @ -direction).max())
        start = centre + shift * lateral - (rear + PUSHER_HALF_DEPTH + PUSH_GAP) * direction
        travel = self.push_distance - PUSH_GAP
        everything = np.concatenate(list(objects.values()))
        relative = everything[:, :2] - start
        at_start = (np.abs(relative @ direction) < PUSHER_HALF_DEPTH + CLEARANCE) & (
            np.abs(relative @ lateral) < PUSHER_HALF_WIDTH + CLEARANCE
        )
        if np.any(at_start & (everything[:, 2] > PUSH_HEIGHT - 0.01)):
            return None
        moved, target = set(), None
        for other, other_points in scene.objects.items():
            relative = other_points[:, :2] - start
            ahead = relative @ direction
            band = (np.abs(relative @ lateral) < PUSHER_HALF_WIDTH) & (ahead > 0)
            if not np.any(band & (ahead < travel + PUSHER_HALF_DEPTH)):
                continue
            if other in clumps and not np.all(band):  # the band's part of the clump goes, the rest stays
                piece = max(objects) + 1
                objects[other], objects[piece], headings[piece] = (
                    other_points[~band],
                    other_points[band],
                    headings.get(other, ()),
                )
                moved.add(piece)
            else:
                piece = other
                moved.add(other)
            if other == index:
                target = piece
        if target is None:
            return None
        step = travel * direction
        frontier = list(moved)
        while frontier:
            swept = np.concatenate([objects[i][:, :2] + f * step for i in frontier for f in (0.25, 0.5, 0.75, 1.0)])
            frontier = []
            for other, other_points in objects.items():
                if other not in moved and _near(other_points[:, :2], swept):
                    moved.add(other)
                    frontier.append(other)
        shifted = np.array([*step, 0.0])
        after = PackedScene({i: p + shifted if i in moved else p for i, p in objects.items()}, headings)
        for i in moved:
            xy = after.objects[i][:, :2].mean(axis=0)
            if not np.all((xy >= PLAY_REGION[:, 0] + 0.03) & (xy <= PLAY_REGION[:, 1] - 0.03)):
                return None
        return self.clearance(after), -len(moved), start

    @staticmethod
    def shifts(points: np.ndarray, heading: float, clump: bool) -> tuple[float, ...]:
        """Sideways shifts (metres, to the left) of pushes along ``heading`` behind an object with ``columns``
        ``points``: ``PUSH_SHIFTS``, and for a ``clump`` those that put its outermost ``CLUMP_EDGE`` on either
        side under the fingers."""
        if not clump:
            return PUSH_SHIFTS
        lateral = np.array([-np.sin(heading), np.cos(heading)])
        offsets = (points[:, :2] - points[:, :2].mean(axis=0)) @ lateral
        edge = PUSHER_HALF_WIDTH - CLUMP_EDGE
        return (*PUSH_SHIFTS, float(offsets.max()) + edge, float(offsets.min()) - edge)

    def choose(
        self, scene: PackedScene, tried: Callable[[GraspCandidate], bool], rng: np.random.Generator | None = None
    ) -> PackedDecision:
        """The first clear grasp not ``tried`` yet; else (with pushes) the push that frees the most objects
        -- if none frees one, the one that most clears the way of the least blocked grasp -- unless no push does
        better than trying that grasp as it is; else that grasp.  Of equally good pushes the first (or, given
        ``rng``, one drawn at random: a clump's seams may run either way)."""
        ranked = [(blocked, c) for blocked, c in self.grasps(scene) if not tried(c)]
        clear = [c for blocked, c in ranked if blocked == 0]
        if clear:
            return PackedDecision(clear[0], clear=True)
        if self.push_distance is not None and scene.objects:
            clumps = self.clumps(scene)
            outcomes = [
                (outcome, heading)
                for index, points in scene.objects.items()
                for heading in PUSH_HEADINGS
                for shift in self.shifts(points, heading, index in clumps)
                if (outcome := self.push_outcome(scene, index, heading, shift, clumps)) is not None
            ]
            best = max((outcome[:2] for outcome, _ in outcomes), default=None)
            if best is not None and best[0] > (0, -ranked[0][0] if ranked else 0):
                tied = [item for item in outcomes if item[0][:2] == best]
                (_, _, start), heading = tied[0] if rng is None else tied[int(rng.integers(len(tied)))]
                return PackedDecision(push_start=start, push_heading=float(heading))
        return PackedDecision(ranked[0][1] if ranked else None)
