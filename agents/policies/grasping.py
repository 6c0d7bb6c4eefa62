"""The planned grasp loop as an agent: perceive, detect and select a grasp, act; on failure re-perceive and
retry with the next candidate.

Stages of the source study's loop and where they happen here: the robot waits
at home (the env's primitives end there); the camera captures RGB-D (the
observation); grasps are proposed from the depth image without object models
(``panda_grasp_env.perception.grasps``); the best untried one is selected; the env's grasp
primitive moves, closes, lifts and verifies (finger gap, then lift without
dropping); on failure the arm has retreated home and the loop repeats with the
next candidate.  When no untried candidate is left, ``push_planner.PushPlanner`` works on the objects the depth
image shows one by one (``camera_scene``): a grasp that clears the neighbours, or the push that best frees one
from them.  The push-aware oracle (``PackedGraspOracle``) runs the same planner on the true shapes.
"""

from __future__ import annotations

import time
from collections import Counter
from typing import Any

import gymnasium as gym
import numpy as np

from panda_grasp_env.actions import encode_grasp_pose
from panda_grasp_env.agents.policies.base import CameraViews, PrimitiveActionWriter, record_failure
from panda_grasp_env.agents.policies.push_planner import (
    PLAY_REGION,
    PUSH_HEIGHT,
    PackedDecision,
    PackedScene,
    PushPlanner,
    camera_scene,
    footprint,
)
from panda_grasp_env.agents.policies.registry import register_baseline
from panda_grasp_env.geometry import top_down_rotation
from panda_grasp_env.perception.grasps import GraspCandidate, detect_grasps_rgbd
from panda_grasp_env.perception.pose import View

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
