"""PutInBin: blocks on the table, an open bin beside them; put the named block into the bin.

The whole task is this file: its scene (the blocks, and the bin it builds as a fixture), its reset,
its verdict and its Gymnasium id.  World frame, metres, radians.
"""

from __future__ import annotations

from typing import Any

import mujoco
import numpy as np

from panda_grasp_env.geometry import is_count, is_number, yaw_quaternion
from panda_grasp_env.model.scene import DEFAULT_COLOURS, SceneConfig
from panda_grasp_env.primitives.result import PrimitiveResult
from panda_grasp_env.registration import EnvId, register_task
from panda_grasp_env.sim.workcell import SPAWN_REGION, Workcell, scattered_layout
from panda_grasp_env.tasks.base import Task, TaskStep, check_option, with_scene

#: Inside of the bin: half-width of its square floor, and the height of its walls above the floor, metres.
INNER_HALF_WIDTH = 0.065
WALL_HEIGHT = 0.04
WALL_THICKNESS = 0.008
FLOOR_THICKNESS = 0.005
BIN_COLOUR = (0.33, 0.34, 0.37, 1.0)  # grey: no block colour's hue


@register_task
class PutInBin(Task):
    """Put the named block into the bin.

    Options: ``n_blocks`` (1-4, default 3; the scene's colours in order); ``target``: the block's
    colour (``"red"``, ...), or None to draw one per episode (default); ``bin_position``: (x, y) of
    the bin's centre, metres (default (0.6, 0.15): inside the default heightmap, clear of the blocks'
    start region's middle).  Blocks start scattered outside the bin.

    The target is observed as the one-hot ``command`` (in colour order) and named in ``info["target"]``;
    ``info`` also gives ``bin_position`` (x, y, z of the bin's floor top) and ``bin_inner_half_width``.
    Success: the target rests inside the bin, released, with no other block in it; the episode then
    terminates, as it does when the target leaves the table.  Reward: 1 on success, else 0.
    """

    name = "PutInBin"
    primitives = ("grasp", "place")
    env_ids = {"PandaPutInBin-v0": EnvId(10)}

    def __init__(
        self, n_blocks: int = 3, target: str | None = None, bin_position: tuple[float, float] = (0.6, 0.15)
    ) -> None:
        check_option("n_blocks", n_blocks, is_count(n_blocks) and 1 <= n_blocks <= 4, "an int in [1, 4]")
        colours = list(DEFAULT_COLOURS)[:n_blocks]
        check_option("target", target, target is None or target in colours, f"None or one of {colours}")
        position = tuple(bin_position) if isinstance(bin_position, (tuple, list)) else ()
        valid = len(position) == 2 and all(map(is_number, position))
        valid = valid and 0.35 <= position[0] <= 0.65 and abs(position[1]) <= 0.25
        check_option("bin_position", bin_position, valid, "(x, y) with 0.35 <= x <= 0.65 and |y| <= 0.25 m")
        self.n_blocks, self.colours, self.target = n_blocks, colours, target
        self.bin_position = np.array([float(position[0]), float(position[1])])
        self.command_size = n_blocks
        self._target_index = 0

    def scene_config(self, base: SceneConfig) -> SceneConfig:
        return with_scene(base, n_blocks=self.n_blocks, n_objects=0)

    def add_fixtures(self, spec: mujoco.MjSpec) -> None:
        """The bin: a floor plate and four walls, one static body on the table."""
        body = spec.worldbody.add_body()
        body.name = "bin"
        body.pos = [*self.bin_position, 0.0]
        outer = INNER_HALF_WIDTH + WALL_THICKNESS
        wall_centre = INNER_HALF_WIDTH + WALL_THICKNESS / 2
        wall_z = FLOOR_THICKNESS + WALL_HEIGHT / 2
        plates = {
            "bin_floor": ([outer, outer, FLOOR_THICKNESS / 2], [0.0, 0.0, FLOOR_THICKNESS / 2]),
            "bin_wall_+x": ([WALL_THICKNESS / 2, outer, WALL_HEIGHT / 2], [wall_centre, 0.0, wall_z]),
            "bin_wall_-x": ([WALL_THICKNESS / 2, outer, WALL_HEIGHT / 2], [-wall_centre, 0.0, wall_z]),
            "bin_wall_+y": ([INNER_HALF_WIDTH, WALL_THICKNESS / 2, WALL_HEIGHT / 2], [0.0, wall_centre, wall_z]),
            "bin_wall_-y": ([INNER_HALF_WIDTH, WALL_THICKNESS / 2, WALL_HEIGHT / 2], [0.0, -wall_centre, wall_z]),
        }
        for name, (size, position) in plates.items():
            geom = body.add_geom()
            geom.name, geom.type, geom.size, geom.pos = name, mujoco.mjtGeom.mjGEOM_BOX, size, position
            geom.rgba = BIN_COLOUR

    @property
    def ideal_actions(self) -> int:
        return 2

    def command(self) -> np.ndarray:
        return np.eye(self.n_blocks, dtype=np.float32)[self._target_index]

    def in_bin(self, position: np.ndarray, block_size: float) -> bool:
        """Whether a block centre (world, metres) lies over the bin's floor, less than a block above its walls
        (in it, or on a block in it; not carried over it)."""
        inside = np.all(np.abs(position[:2] - self.bin_position) < INNER_HALF_WIDTH)
        return bool(inside and position[2] < FLOOR_THICKNESS + WALL_HEIGHT + block_size)

    def reset(self, cell: Workcell, rng: np.random.Generator) -> dict[str, Any]:
        cell.clear()
        size = cell.config.block_size
        keep_out = INNER_HALF_WIDTH + WALL_THICKNESS + size  # a block's half-diagonal plus room for a finger
        while True:
            positions, yaws = scattered_layout(rng, self.n_blocks, size, SPAWN_REGION)
            if np.all(np.max(np.abs(positions[:, :2] - self.bin_position), axis=1) > keep_out):
                break
        for body_id, position, yaw in zip(cell.block_ids, positions, yaws):
            cell.set_body_pose(body_id, position, yaw_quaternion(yaw))
        self._target_index = self.colours.index(self.target) if self.target else int(rng.integers(self.n_blocks))
        cell.settle(0.1)
        return {
            "target": cell.block_names[self._target_index],
            "bin_position": np.array([*self.bin_position, FLOOR_THICKNESS]),
            "bin_inner_half_width": INNER_HALF_WIDTH,
            **self._contents(cell),
        }

    def _contents(self, cell: Workcell) -> dict[str, Any]:
        inside = [self.in_bin(p, cell.config.block_size) for p in cell.block_positions()]
        return {"target_in_bin": inside[self._target_index], "others_in_bin": sum(inside) - inside[self._target_index]}

    def evaluate(self, cell: Workcell, result: PrimitiveResult | None) -> TaskStep:
        contents = self._contents(cell)
        target = int(cell.block_ids[self._target_index])
        released = target not in cell.robot.bodies_between_fingers()
        success = contents["target_in_bin"] and released and contents["others_in_bin"] == 0
        return TaskStep(float(success), success, success or cell.is_parked(target), contents)
