"""The planned grasp loop as an agent: perceive, detect and select a grasp, act; on failure re-perceive and
retry with the next candidate.

Stages of the source study's loop and where they happen here: the robot waits
at home (the env's primitives end there); the camera captures RGB-D (the
observation); grasps are proposed from the depth image without object models
(``panda_grasp_env.perception.grasps``); the best untried one is selected; the env's grasp
primitive moves, closes, lifts and verifies (finger gap, then lift without
dropping); on failure the arm has retreated home and the loop repeats with the
next candidate.
"""

from __future__ import annotations

import time
from collections import Counter
from typing import Any

import gymnasium as gym
import numpy as np

from panda_grasp_env.actions import encode_grasp_pose
from panda_grasp_env.agents.base import CameraViews, PrimitiveActionWriter, record_failure
from panda_grasp_env.agents.registry import register_baseline
from panda_grasp_env.geometry import top_down_rotation
from panda_grasp_env.perception.grasps import GraspCandidate, GripperGeometry, detect_grasps_rgbd
from panda_grasp_env.perception.heightmap import DEFAULT_BOUNDS

#: A candidate this close (metres, radians) to a failed attempt is not tried again.
RETRY_DISTANCE = 0.01
RETRY_HEADING = np.deg2rad(15)


class PlannedGraspAgent:
    """Grasps with the top-ranked detected candidate that has not failed yet; pushes the heap when none is left.

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
        self.rng = np.random.default_rng(self.seed)
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
        """Ranked grasp candidates from the overhead depth image."""
        view = self.views(observation)[0]
        return detect_grasps_rgbd(view.depth, view.camera, self.rng)

    def act(self, observation: Any, info: dict[str, Any]) -> np.ndarray:
        record_failure(self.failures, info)
        if self.last is not None and info.get("primitive") == "grasp" and not info["primitive_success"]:
            self.failed.append((self.last.position, self.last.yaw))
        start = time.perf_counter()
        ranked = self.candidates(observation)
        untried = [c for c in ranked if not self._tried(c)]
        self.compute_seconds.append(time.perf_counter() - start)
        if not untried:
            self.failures["no_candidate"] += 1
            self.last = None
            return self._push_or_wait(ranked)
        self.last = untried[0]
        return self._grasp_action(self.last)

    def _push_or_wait(self, ranked: list[GraspCandidate]) -> np.ndarray:
        """No untried grasp: push through the best-ranked object's centre to change the scene (VPG's other
        primitive), or retry the best candidate if pushing is not offered."""
        best = ranked[0] if ranked else None
        if self.pose_mode or "push" not in self.write.primitives:
            if best is None:  # nothing seen: a harmless grasp at an empty corner of the table
                best = GraspCandidate(np.array([0.3, 0.3, 0.02]), top_down_rotation(0.0), 0.0, 0.0, 0.0, -1)
            return self._grasp_action(best)
        centre = best.position[:2] if best is not None else np.array([0.5, 0.0])
        heading = float(self.rng.uniform(-np.pi, np.pi))
        start = centre - 0.06 * np.array([np.cos(heading), np.sin(heading)])
        return self.write("push", start[0], start[1], heading, 0.03)


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


def _near(points: np.ndarray, others: np.ndarray) -> bool:
    """Whether any of ``points`` (N, 2) lies within ``SAMPLE_SPACING`` of any of ``others`` (M, 2), metres."""
    low, high = others.min(axis=0) - SAMPLE_SPACING, others.max(axis=0) + SAMPLE_SPACING
    candidates = points[np.all((points >= low) & (points <= high), axis=1)]
    if not len(candidates):
        return False
    return bool(np.min(np.linalg.norm(candidates[:, None] - others[None], axis=2)) < SAMPLE_SPACING)


def footprint(model: Any, data: Any, body: int) -> np.ndarray:
    """Columns (N, 3) covering the first geom of ``body`` seen from above: world x, y and the top z of the
    geom over that point (metres), on a ``SAMPLE_SPACING`` grid."""
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
    points = local @ data.xmat[body].reshape(3, 3).T + data.xpos[body]
    cells, inverse = np.unique(np.round(points[:, :2] / SAMPLE_SPACING).astype(int), axis=0, return_inverse=True)
    tops = np.full(len(cells), -np.inf)
    np.maximum.at(tops, inverse.ravel(), points[:, 2])
    return np.column_stack([cells * SAMPLE_SPACING, tops])


class PackedGraspOracle(OracleGraspAgent):
    """*Oracle* for packed scenes: true object poses and shapes; grasps only where the open fingers and the
    palm clear every other object; with ``pushes``, a planned push when no such grasp is left.

    Grasps: for each object in play, at each of ``GRASP_HEADINGS`` and across its own faces, a top-down grasp through its centre
    (``grasp_depth`` below its top) whose width across the fingers fits the hand.  Clear: no point of
    another object (``footprint``) inside either open finger's box, from the fingertips up, or under
    the palm.  The clear candidate across the narrowest width is tried first; one that failed is not tried
    again (as ``PlannedGraspAgent``).

    Pushes (VPG's other primitive, ``pushes=True``) when no clear grasp is left: for each object and each of
    ``PUSH_HEADINGS`` the closed fingers start just behind it -- where they clear everything -- and push
    ``push_distance``; the object and whatever its sweep meets (transitively) are predicted to move along
    with it.  The push that leaves the most objects with a clear grasp (then: the least blocked grasp
    freest; then: moving the fewest; never one that moves an object out of the play region) is made, if
    it does better than the scene as it is.  Without ``pushes`` (the grasp-only oracle), or when no push
    helps, it tries the grasp that collides least.  It plays in ``primitive`` mode (``primitive_z=True``) or,
    its choices rounded to the nearest cell and heading, in ``pixel`` mode: the demonstrator of
    ``heightmap_dqn_demos``.
    """

    name = "packed_grasp_oracle"

    def __init__(self, env: gym.Env, seed: int = 0, pushes: bool = True) -> None:
        super().__init__(env, seed)
        self.pushes = pushes
        self.gripper = GripperGeometry()
        self.push_distance = 0.1
        self.play_region: np.ndarray | None = None
        self._face_headings: dict[int, tuple[float, float]] = {}

    def reset(self, observation: Any, info: dict[str, Any]) -> None:
        super().reset(observation, info)
        layout = info.get("action_layout", {})
        self.push_distance = float(layout["push_distance"])
        self.play_region = np.asarray(DEFAULT_BOUNDS[:2])

    def _objects(self) -> dict[int, np.ndarray]:
        """``footprint`` of every object on the table inside the play region, by index in ``object_ids``."""
        cell = self.cell
        objects = {}
        for index, body in enumerate(cell.object_ids):
            xy = cell.data.xpos[body][:2]
            inside = np.all((xy >= self.play_region[:, 0]) & (xy <= self.play_region[:, 1]))
            if cell.data.xpos[body][2] > -0.05 and inside:
                objects[index] = footprint(cell.model, cell.data, body)
                # Across its faces too, not only at the fixed headings (a box turned between two of them).
                x_axis = cell.data.xmat[body].reshape(3, 3)[:, 0]
                heading = float(np.arctan2(x_axis[1], x_axis[0]))
                self._face_headings[index] = (heading % np.pi, (heading + np.pi / 2) % np.pi)
        return objects

    def _grasps(self, objects: dict[int, np.ndarray]) -> list[tuple[int, GraspCandidate]]:
        """(points of other objects in the hand's way, candidate) for every fitting grasp, fewest first."""
        g = self.gripper
        ranked = []
        for index, points in objects.items():
            others = np.concatenate([p for i, p in objects.items() if i != index] or [np.zeros((0, 3))])
            centre, top = points[:, :2].mean(axis=0), points[:, 2].max()
            z = max(top - g.grasp_depth, g.min_height)
            for yaw in (*GRASP_HEADINGS, *self._face_headings.get(index, ())):
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

    def _clearance(self, objects: dict[int, np.ndarray]) -> tuple[int, int]:
        """(objects with at least one clear grasp, minus the points in the way of the least blocked grasp)."""
        ranked = self._grasps(objects)
        return len({c.object_index for blocked, c in ranked if blocked == 0}), -(ranked[0][0] if ranked else 0)

    def _push_outcome(self, objects: dict[int, np.ndarray], index: int, heading: float, shift: float) -> tuple | None:
        """(``_clearance`` after, -objects moved, start xy) of a push along ``heading`` that starts
        just behind object ``index``, ``shift`` metres to the left of its centre line; None if the closed
        fingers cannot come down there or something would leave the play region.

        The closed fingers are a ``PUSHER_HALF_WIDTH`` x ``PUSHER_HALF_DEPTH`` box; every object whose
        footprint the box sweeps moves the full stroke less the start gap, and so does whatever those sweep
        on (transitively)."""
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
        moved = set()
        for other, other_points in objects.items():
            relative = other_points[:, :2] - start
            ahead = relative @ direction
            inside = (
                (np.abs(relative @ lateral) < PUSHER_HALF_WIDTH) & (ahead > 0) & (ahead < travel + PUSHER_HALF_DEPTH)
            )
            if np.any(inside):
                moved.add(other)
        if index not in moved:
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
        after = {i: p + np.array([*step, 0.0]) if i in moved else p for i, p in objects.items()}
        for i in moved:
            xy = after[i][:, :2].mean(axis=0)
            if not np.all((xy >= self.play_region[:, 0] + 0.03) & (xy <= self.play_region[:, 1] - 0.03)):
                return None
        return self._clearance(after), -len(moved), start

    def act(self, observation: Any, info: dict[str, Any]) -> np.ndarray:
        record_failure(self.failures, info)
        if self.last is not None and info.get("primitive") == "grasp" and not info["primitive_success"]:
            self.failed.append((self.last.position, self.last.yaw))
        start = time.perf_counter()
        objects = self._objects()
        ranked = [(blocked, c) for blocked, c in self._grasps(objects) if not self._tried(c)]
        clear = [c for blocked, c in ranked if blocked == 0]
        action = None
        if clear:
            self.last = clear[0]
        elif self.pushes and objects:
            outcomes = [
                (outcome, heading)
                for index in objects
                for heading in PUSH_HEADINGS
                for shift in PUSH_SHIFTS
                if (outcome := self._push_outcome(objects, index, heading, shift)) is not None
            ]
            # The push that frees the most objects; if none frees one, the one that most clears the way of the
            # least blocked grasp -- unless no push does better than trying that grasp as it is.
            best = max(outcomes, key=lambda item: item[0][:2], default=None)
            if best is not None and best[0][0] > (0, -ranked[0][0] if ranked else 0):
                (_, _, push_start), heading = best
                self.last = None
                action = self.write("push", push_start[0], push_start[1], float(heading), PUSH_HEIGHT)
        if action is None:
            if not clear:
                self.failures["no_clear_grasp"] += 1
                # The least blocked grasp, or, with nothing that fits the hand, a harmless one at an empty corner.
                empty = GraspCandidate(np.array([0.3, 0.3, 0.02]), top_down_rotation(0.0), 0.0, 0.0, 0.0, -1)
                self.last = ranked[0][1] if ranked else empty
            action = self._grasp_action(self.last)
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
