"""Shelf: put the block on a shelf that stands somewhere else every episode -- a task, its benchmark and its
planned agent written outside the package, in one file.

    python evaluate.py --import docs.examples.shelf_task --tasks Shelf --agents planned,random

The shelf is a fixture with state: ``add_fixtures`` builds it once, and ``reset`` moves and resizes it for
each episode (``cell.fixtures.set_pose`` / ``set_size``), so transit heights, the heights the
env picks for a place, the collision check of the primitives and the motion planner all see it where it
stands now.  World frame, metres, radians.
"""

from __future__ import annotations

from collections import Counter
from typing import Any

import mujoco
import numpy as np

from panda_grasp_env.agents.evaluation.benchmarks import Benchmark, register_benchmark
from panda_grasp_env.agents.policies.base import PrimitiveActionWriter, record_failure, require
from panda_grasp_env.agents.policies.registry import register_baseline
from panda_grasp_env.agents.policies.towers import CameraBlocks, OracleBlocks, block_baseline
from panda_grasp_env.geometry import yaw_quaternion
from panda_grasp_env.model.scene import SceneConfig
from panda_grasp_env.primitives.result import PrimitiveResult
from panda_grasp_env.registration import EnvId, register_task
from panda_grasp_env.sim.stacking import clearest_grasp_heading
from panda_grasp_env.sim.workcell import SPAWN_REGION, Workcell
from panda_grasp_env.tasks.base import Task, TaskStep, check_option, is_interval, with_scene

#: Half extents of the shelf's top (x, y in its own frame), metres; its height is drawn per episode.
SHELF_HALF = (0.06, 0.08)
#: The block starts at least this far outside the shelf's footprint (the open hand is ~20 cm across).
KEEP_OUT = 0.1


@register_task
class Shelf(Task):
    """Put the red block on the shelf.  Options: ``heights``, the (low, high) range of the shelf's height,
    metres (default (0.04, 0.1)).  Each episode draws the shelf's place beside the middle of the table, its
    heading and its height; ``info`` gives ``shelf_position`` (x, y and z of its top), ``shelf_yaw`` and
    ``shelf_half_size``.  Success: the block rests released on the shelf's top; the episode then ends, as it
    does when the block leaves the table.  Reward: 1 on success, else 0."""

    name = "Shelf"
    primitives = ("grasp", "place")
    env_ids = {"ShelfPlace-v0": EnvId(10)}

    def __init__(self, heights: tuple[float, float] = (0.04, 0.1)) -> None:
        valid = is_interval(heights) and 0.02 <= heights[0] and heights[1] <= 0.15
        check_option("heights", heights, valid, "(low, high) metres within [0.02, 0.15]")
        self.heights = (float(heights[0]), float(heights[1]))
        self.pose = np.zeros(3)  # x, y, yaw of this episode's shelf
        self.top = 0.0

    def scene_config(self, base: SceneConfig) -> SceneConfig:
        return with_scene(base, n_blocks=1, n_objects=0)

    def add_fixtures(self, spec: mujoco.MjSpec) -> None:
        """The shelf: one static box; ``reset`` sets where it stands and how high it is."""
        shelf = spec.worldbody.add_body()
        shelf.name = "shelf"
        board = shelf.add_geom()
        board.name, board.type = "shelf_board", mujoco.mjtGeom.mjGEOM_BOX
        board.size, board.rgba = [*SHELF_HALF, self.heights[1] / 2], [0.45, 0.45, 0.48, 1.0]

    @property
    def ideal_actions(self) -> int:
        return 2

    def on_shelf(self, position: np.ndarray) -> np.ndarray:
        """A world point in the shelf's frame (x, y about its centre, metres)."""
        c, s = np.cos(self.pose[2]), np.sin(self.pose[2])
        dx, dy = position[0] - self.pose[0], position[1] - self.pose[1]
        return np.array([c * dx + s * dy, -s * dx + c * dy])

    def reset(self, cell: Workcell, rng: np.random.Generator) -> dict[str, Any]:
        cell.clear()
        side = rng.choice([-1.0, 1.0])
        self.pose = np.array([rng.uniform(0.45, 0.6), side * rng.uniform(0.14, 0.24), rng.uniform(-0.8, 0.8)])
        self.top = rng.uniform(*self.heights)
        cell.fixtures.set_size("shelf_board", [*SHELF_HALF, self.top / 2])
        cell.fixtures.set_pose("shelf", [*self.pose[:2], self.top / 2], self.pose[2])
        size = cell.config.block_size
        while True:  # the block on the table, well clear of the shelf
            position = np.array([rng.uniform(*SPAWN_REGION[0]), rng.uniform(*SPAWN_REGION[1]), size / 2])
            if np.any(np.abs(self.on_shelf(position)) > np.array(SHELF_HALF) + KEEP_OUT):
                break
        cell.set_body_pose(cell.block_ids[0], position, yaw_quaternion(rng.uniform(-np.pi / 4, np.pi / 4)))
        cell.settle(0.1)
        return {
            "shelf_position": np.array([*self.pose[:2], self.top]),
            "shelf_yaw": float(self.pose[2]),
            "shelf_half_size": np.array(SHELF_HALF),
            "target": cell.block_names[0],
        }

    def evaluate(self, cell: Workcell, result: PrimitiveResult | None) -> TaskStep:
        block = int(cell.block_ids[0])
        position = cell.data.xpos[block]
        inside = bool(np.all(np.abs(self.on_shelf(position)) < SHELF_HALF))
        resting = abs(position[2] - cell.config.block_size / 2 - self.top) < 0.01
        success = inside and resting and block not in cell.robot.bodies_between_fingers()
        return TaskStep(float(success), success, success or cell.is_parked(block), {"on_shelf": success})


class ShelfAgent:
    """Grasp the block where perception sees it (the heading pointing least at the shelf), then place it
    on the middle of the shelf; after a failed grasp or place, try again from what it sees."""

    def __init__(self, perceiver: CameraBlocks | OracleBlocks) -> None:
        self.perceiver, self.name = perceiver, f"shelf_{perceiver.name}"
        self.failures: Counter[str] = Counter()

    def reset(self, observation: Any, info: dict[str, Any]) -> None:
        require(info, ("shelf_position", "target"), self.name, "use ShelfPlace-v0")
        self.write = PrimitiveActionWriter(info, self.name, ("grasp", "place"))
        self.perceiver.reset(observation, info, self.name)
        self.shelf, self.target = np.asarray(info["shelf_position"], dtype=float), info["target"]
        self.heading: float | None = None  # the grasp heading while the block is in the hand
        self.failures = Counter()

    def act(self, observation: Any, info: dict[str, Any]) -> np.ndarray:
        record_failure(self.failures, info)
        if info.get("primitive") == "place" or (info.get("primitive") == "grasp" and not info["primitive_success"]):
            self.heading = None
        if self.heading is not None:
            return self.write("place", self.shelf[0], self.shelf[1], self.heading)
        blocks = self.perceiver(observation)
        if self.target not in blocks:
            self.failures["no_candidate"] += 1
            return self.write("grasp", 0.3, -0.3, 0.0, 0.02)  # nothing seen: a harmless miss
        block = blocks[self.target]
        self.heading = clearest_grasp_heading(np.array([block.position, self.shelf]), 0, block.yaw)
        return self.write("grasp", block.position[0], block.position[1], self.heading, block.position[2])


register_benchmark("Shelf", Benchmark("ShelfPlace-v0", quick_seeds=10, full_seeds=100))
register_baseline("Shelf")(block_baseline(ShelfAgent))
