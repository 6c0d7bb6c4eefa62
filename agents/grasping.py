"""The planned grasp loop as an agent: perceive, detect and select a grasp, act; on failure re-perceive and
retry with the next candidate.

Stages of the source study's loop and where they happen here: the robot waits
at home (the env's primitives end there); the camera captures RGB-D (the
observation); grasps are proposed from the depth image without object models
(``panda_grasp_env.perception.grasps``); the best untried one is selected; the env's grasp
primitive moves, closes, lifts and verifies (finger gap, then lift without
dropping); on failure the arm has retreated home and the loop repeats with the
next candidate.  When no untried candidate is left, ``PushPlanner`` works on the objects the depth image shows
one by one (``camera_scene``): a grasp that clears the neighbours, or the push that best frees one from them.
The push-aware oracle (``PackedGraspOracle``) runs the same planner on the true shapes.
"""

from __future__ import annotations

import time
from collections import Counter
from collections.abc import Callable
from dataclasses import dataclass
from typing import Any

import gymnasium as gym
import numpy as np

from panda_grasp_env.actions import encode_grasp_pose
from panda_grasp_env.agents.base import CameraViews, PrimitiveActionWriter, record_failure
from panda_grasp_env.agents.registry import register_baseline
from panda_grasp_env.geometry import top_down_rotation
from panda_grasp_env.perception.grasps import (
    REGION_OF_INTEREST,
    GraspCandidate,
    GripperGeometry,
    ObjectOutline,
    detect_grasps_rgbd,
)
from panda_grasp_env.perception.heightmap import DEFAULT_BOUNDS
from panda_grasp_env.perception.pose import View
from panda_grasp_env.perception.segmentation import fit_plane_ransac, object_tops, region_points

#: A candidate this close (metres, radians) to a failed attempt is not tried again.
RETRY_DISTANCE = 0.01
RETRY_HEADING = np.deg2rad(15)
#: With nothing to grasp: a harmless grasp at an empty corner of the table (world metres).
EMPTY_CORNER_GRASP = GraspCandidate(np.array([0.3, 0.3, 0.02]), top_down_rotation(0.0), 0.0, 0.0, 0.0, -1)


class PlannedGraspAgent:
    """Grasps with the top-ranked detected candidate that has not failed yet; when none is left, lets
    ``PushPlanner`` choose on the camera's view of the objects (``camera_scene``): a grasp it finds clear of the
    neighbours, else the push that best frees an object (where pushes are offered), else the least blocked grasp.

    Needs ``action_mode='grasp_pose'`` (6-DOF grasps through the env's motion stack) or
    ``action_mode='primitive'`` with ``primitive_z=True`` (top-down grasp primitive), and
    ``obs_mode='rgbd'`` with the overhead camera at 640 x 480.  ``noise_seed`` runs the images
    through the Kinect-like noise model (None: the clean renders).
    """

    name = "planned_grasp"

    def __init__(self, noise_seed: int | None = 0, seed: int = 0) -> None:
        self.noise_seed, self.seed = noise_seed, seed
        self.failures: Counter[str] = Counter()
        self.compute_seconds: list[float] = []

    def reset(self, observation: Any, info: dict[str, Any]) -> None:
        self._choose_writer(info)
        self.views = CameraViews(observation, info, self.name, ("overhead",), self.noise_seed)
        self.view: View | None = None
        self.rng = np.random.default_rng(self.seed)
        pushes = not self.pose_mode and "push" in self.write.primitives
        self.planner = PushPlanner(float(info["action_layout"]["push_distance"]) if pushes else None)
        self.failed: list[tuple[np.ndarray, float]] = []
        self.last: GraspCandidate | None = None
        self.failures = Counter()
        self.compute_seconds = []

    def _choose_writer(self, info: dict[str, Any]) -> None:
        # With action_mode='grasp_pose' the full 6-DOF candidate goes through the env's motion stack;
        # with 'primitive' (primitive_z=True) through the top-down grasp primitive; with 'pixel' (the oracles,
        # which need no images) at the nearest cell and heading, the env choosing the height.
        self.pose_mode = info.get("action_layout", {}).get("mode") == "grasp_pose"
        self.write = None if self.pose_mode else PrimitiveActionWriter(info, self.name, ("grasp",), needs_z=True)

    def _grasp_action(self, candidate: GraspCandidate) -> np.ndarray:
        if self.pose_mode:
            return encode_grasp_pose(candidate.position, candidate.rotation)
        x, y, z = candidate.position
        return self.write("grasp", x, y, candidate.yaw, z)

    def _tried(self, candidate: GraspCandidate) -> bool:
        for position, yaw in self.failed:
            turn = abs((candidate.yaw - yaw + np.pi / 2) % np.pi - np.pi / 2)
            if np.linalg.norm(candidate.position[:2] - position[:2]) < RETRY_DISTANCE and turn < RETRY_HEADING:
                return True
        return False

    def candidates(self, observation: Any) -> list[GraspCandidate]:
        """Ranked grasp candidates from the overhead depth image (kept as ``view`` for the push planner)."""
        self.view = self.views(observation)[0]
        return detect_grasps_rgbd(self.view.depth, self.view.camera, self.rng)

    def _note_failure(self, info: dict[str, Any]) -> None:
        """Count the last primitive's failure; remember a failed grasp so that it is not tried again."""
        record_failure(self.failures, info)
        if self.last is not None and info.get("primitive") == "grasp" and not info["primitive_success"]:
            self.failed.append((self.last.position, self.last.yaw))

    def act(self, observation: Any, info: dict[str, Any]) -> np.ndarray:
        self._note_failure(info)
        start = time.perf_counter()
        ranked = self.candidates(observation)
        untried = [c for c in ranked if not self._tried(c)]
        if untried:
            self.last = untried[0]
            action = self._grasp_action(self.last)
        else:
            self.failures["no_candidate"] += 1
            action = self._without_candidate(ranked)
        self.compute_seconds.append(time.perf_counter() - start)
        return action

    def _without_candidate(self, ranked: list[GraspCandidate]) -> np.ndarray:
        """No untried candidate: ``PushPlanner``'s choice on the objects of the image the detector saw."""
        return self._decided(self.planner.choose(camera_scene(self.view, self.rng), self._tried, self.rng))

    def _decided(self, decision: PackedDecision) -> np.ndarray:
        """The action of a ``PushPlanner`` decision (a grasp at an empty corner when it holds none)."""
        if decision.push_start is not None:
            self.last = None
            x, y = decision.push_start
            return self.write("push", x, y, decision.push_heading, PUSH_HEIGHT)
        self.last = decision.grasp or EMPTY_CORNER_GRASP
        return self._grasp_action(self.last)


class OracleGraspAgent(PlannedGraspAgent):
    """*Oracle*: the same loop, with candidates made from the simulator's true object poses and shapes
    (a top-down grasp through each object's centre, across its narrowest horizontal side)."""

    name = "oracle_grasp"

    def __init__(self, env: gym.Env, seed: int = 0) -> None:
        super().__init__(noise_seed=None, seed=seed)
        self.cell = env.unwrapped.cell

    def reset(self, observation: Any, info: dict[str, Any]) -> None:
        self._choose_writer(info)
        self.rng = np.random.default_rng(self.seed)
        self.failed, self.last = [], None
        self.failures, self.compute_seconds = Counter(), []

    def _without_candidate(self, ranked: list[GraspCandidate]) -> np.ndarray:
        """No untried candidate: push through the best-ranked object's centre at a random heading to change the
        scene (VPG's other primitive), or retry the best candidate if pushing is not offered."""
        best = ranked[0] if ranked else None
        if self.pose_mode or "push" not in self.write.primitives:
            self.last = best or EMPTY_CORNER_GRASP
            return self._grasp_action(self.last)
        self.last = None
        centre = best.position[:2] if best is not None else np.array([0.5, 0.0])
        heading = float(self.rng.uniform(-np.pi, np.pi))
        start = centre - 0.06 * np.array([np.cos(heading), np.sin(heading)])
        return self.write("push", start[0], start[1], heading, 0.03)

    def candidates(self, observation: Any) -> list[GraspCandidate]:
        cell, model = self.cell, self.cell.model
        ranked = []
        for index, body in enumerate(cell.object_ids):
            position = cell.data.xpos[body]
            if position[2] < -0.05:
                continue
            geom = model.body_geomadr[body]
            rotation = cell.data.xmat[body].reshape(3, 3)
            # Closing axis: the body axis with the smallest horizontal extent (capsules lie along local z).
            extents = model.geom_size[geom].copy()
            if int(model.geom_type[geom]) in (3, 5):  # capsule, cylinder: (radius, half length)
                extents = np.array(
                    [extents[0], extents[0], extents[1] + (extents[0] if int(model.geom_type[geom]) == 3 else 0)]
                )
            horizontal = [i for i in range(3) if abs(rotation[2, i]) < 0.7]
            axis = min(horizontal, key=lambda i: extents[i]) if horizontal else 0
            yaw = float(np.arctan2(rotation[1, axis], rotation[0, axis]))
            top = position[2] + float(np.abs(rotation[2]) @ extents)
            grasp = np.array([position[0], position[1], max(top - 0.035, 0.02)])
            ranked.append(
                GraspCandidate(grasp, top_down_rotation(yaw), 2 * extents[axis], 1.0 - 0.01 * index, yaw, index)
            )
        return ranked


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
    the true shapes for ``PackedGraspOracle``, the camera's object tops for ``PlannedGraspAgent``.

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


class PackedGraspOracle(OracleGraspAgent):
    """*Oracle* for packed scenes: ``PushPlanner`` on the true object poses and shapes (``footprint``); grasps
    only where the open fingers and the palm clear every other object; with ``pushes``, a planned push when no
    such grasp is left.

    The clear candidate across the narrowest width is tried first; one that failed is not tried again (as
    ``PlannedGraspAgent``).  Without ``pushes`` (the grasp-only oracle), or when no push helps, it tries the
    grasp that collides least.  It plays in ``primitive`` mode (``primitive_z=True``) or, its choices rounded to
    the nearest cell and heading, in ``pixel`` mode: the demonstrator of ``heightmap_dqn_demos``.
    """

    name = "packed_grasp_oracle"

    def __init__(self, env: gym.Env, seed: int = 0, pushes: bool = True) -> None:
        super().__init__(env, seed)
        self.pushes = pushes

    def reset(self, observation: Any, info: dict[str, Any]) -> None:
        super().reset(observation, info)
        self.planner = PushPlanner(float(info["action_layout"]["push_distance"]) if self.pushes else None)

    def scene(self) -> PackedScene:
        """The true ``footprint`` of every object on the table inside ``PLAY_REGION``, by index in
        ``object_ids``, with the headings of its faces."""
        cell = self.cell
        objects, headings = {}, {}
        for index, body in enumerate(cell.object_ids):
            xy = cell.data.xpos[body][:2]
            inside = np.all((xy >= PLAY_REGION[:, 0]) & (xy <= PLAY_REGION[:, 1]))
            if cell.data.xpos[body][2] > -0.05 and inside:
                objects[index] = footprint(cell.model, cell.data, body)
                # Across its faces too, not only at the fixed headings (a box turned between two of them).
                x_axis = cell.data.xmat[body].reshape(3, 3)[:, 0]
                heading = float(np.arctan2(x_axis[1], x_axis[0]))
                headings[index] = (heading % np.pi, (heading + np.pi / 2) % np.pi)
        return PackedScene(objects, headings)

    def act(self, observation: Any, info: dict[str, Any]) -> np.ndarray:
        self._note_failure(info)
        start = time.perf_counter()
        decision = self.planner.choose(self.scene(), self._tried)
        if decision.push_start is None and not decision.clear:
            self.failures["no_clear_grasp"] += 1
        action = self._decided(decision)
        self.compute_seconds.append(time.perf_counter() - start)
        return action


@register_baseline(
    "Grasp", "GraspClutter", "GraspMeshTrain", "GraspMeshTest", "GraspMeshClutterTrain", "GraspMeshClutterTest"
)
def grasp_baseline(env: gym.Env, seed: int, oracle: bool) -> PlannedGraspAgent:
    """The planned grasping agent (RGB-D grasp detection, noise and restarts seeded), or the oracle."""
    return OracleGraspAgent(env, seed=seed) if oracle else PlannedGraspAgent(noise_seed=seed, seed=seed)


@register_baseline("GraspAdversarial")
def packed_grasp_baseline(env: gym.Env, seed: int, oracle: bool) -> PlannedGraspAgent:
    """The planned grasping agent (it pushes at random when no grasp is detected), or the push-aware oracle."""
    return PackedGraspOracle(env, seed=seed) if oracle else PlannedGraspAgent(noise_seed=seed, seed=seed)
