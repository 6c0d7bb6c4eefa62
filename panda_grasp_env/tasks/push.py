"""Push: push a block into a goal region on the table (goal-conditioned; HER-friendly)."""

from __future__ import annotations

from typing import Any

import numpy as np

from panda_grasp_env.geometry import yaw_quaternion
from panda_grasp_env.model.scene import GOAL_MARKER, SceneConfig
from panda_grasp_env.primitives.result import PrimitiveResult
from panda_grasp_env.registration import EnvId, register_task
from panda_grasp_env.sim.workcell import SPAWN_REGION, Workcell
from panda_grasp_env.tasks.base import (
    GOAL_THRESHOLD,
    Task,
    TaskStep,
    check_option,
    is_interval,
    with_scene,
)


@register_task
class Push(Task):
    """Push the red block until its centre is within 5 cm of a goal on the table.

    Options: ``goal_distance``: (min, max) metres between the block's start and
    the goal (default 0.1-0.25).  The goal is drawn as a translucent green disc.
    Low-level modes: sparse -1/0 reward, never terminates (Fetch convention).
    Primitive modes: reward = progress towards the goal (decimetres) +1 on
    success; terminates on success or if the block leaves the table.
    """

    name = "Push"
    env_ids = {"PandaPush-v0": EnvId(50)}  # 50 steps of 40 ms
    primitives = ("push",)
    goal_conditioned = True
    default_action_mode = "ee_delta"
    start_states = ("behind_object",)

    def __init__(self, goal_distance: tuple[float, float] = (0.1, 0.25)) -> None:
        valid = is_interval(goal_distance) and 0 < goal_distance[0] and goal_distance[1] <= 0.4
        check_option("goal_distance", goal_distance, valid, "(min, max) with 0 < min <= max <= 0.4 m")
        self.goal_distance = (float(goal_distance[0]), float(goal_distance[1]))
        self._goal = np.zeros(3)
        self._distance = 0.0

    def scene_config(self, base: SceneConfig) -> SceneConfig:
        return with_scene(base, n_blocks=1, n_objects=0)

    @property
    def ideal_actions(self) -> int:
        return 1

    def reset(self, cell: Workcell, rng: np.random.Generator) -> dict[str, Any]:
        cell.clear()
        half = cell.config.block_size / 2
        while True:
            start = np.array([rng.uniform(*SPAWN_REGION[0]), rng.uniform(*SPAWN_REGION[1])])
            heading = rng.uniform(-np.pi, np.pi)
            goal = start + rng.uniform(*self.goal_distance) * np.array([np.cos(heading), np.sin(heading)])
            if np.all((goal >= SPAWN_REGION[:, 0]) & (goal <= SPAWN_REGION[:, 1])):
                break
        cell.set_body_pose(cell.block_ids[0], [*start, half], yaw_quaternion(rng.uniform(-np.pi / 4, np.pi / 4)))
        self._goal = np.array([*goal, half])
        marker = cell.model.site(GOAL_MARKER).id
        cell.model.site_pos[marker] = [*goal, 0.0005]
        cell.model.site_size[marker][0] = GOAL_THRESHOLD
        cell.settle(0.1)
        self._distance = self.distance(cell)
        return {"distance_to_goal": self._distance}

    def distance(self, cell: Workcell) -> float:
        """Block centre to goal, metres."""
        offset = cell.data.xpos[cell.block_ids[0]] - self._goal
        return float(np.sqrt(offset @ offset))

    def evaluate(self, cell: Workcell, result: PrimitiveResult | None) -> TaskStep:
        distance = self.distance(cell)
        info = {"distance_to_goal": distance}
        success = distance < GOAL_THRESHOLD
        if result is None:  # sparse goal reward, as compute_reward
            return TaskStep(0.0 if success else -1.0, success, False, info)
        reward = 10.0 * (self._distance - distance) + (1.0 if success else 0.0)
        self._distance = distance
        return TaskStep(reward, success, success or cell.is_parked(cell.block_ids[0]), info)

    def start_object(self, cell: Workcell) -> int:
        """The block to push."""
        return int(cell.block_ids[0])

    def achieved_goal(self, cell: Workcell) -> np.ndarray:
        return cell.data.xpos[cell.block_ids[0]].copy()

    def desired_goal(self) -> np.ndarray:
        return self._goal.copy()
