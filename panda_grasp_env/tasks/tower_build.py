"""TowerBuild: blocks scattered (or lying as a broken tower left them); stack all N on the base block (the first
colour, red by default; its centre at reset is published, so the base is known where all blocks look alike)."""

from __future__ import annotations

from typing import Any

import numpy as np

from panda_grasp_env.geometry import is_number
from panda_grasp_env.model.scene import SceneConfig
from panda_grasp_env.primitives.result import PrimitiveResult
from panda_grasp_env.primitives.top_down import push
from panda_grasp_env.registration import EnvId, register_task
from panda_grasp_env.sim.stacking import stack_column
from panda_grasp_env.sim.stepping import body_speeds
from panda_grasp_env.sim.workcell import SPAWN_REGION, Workcell, tower_layout
from panda_grasp_env.tasks.base import (
    Task,
    TaskStep,
    block_scene,
    check_block_colours,
    check_option,
    check_tower_blocks,
    goals_reached,
)

#: A tower must stand still this long, with the gripper released, to count as built (seconds).
STABLE_TIME = 0.5
#: Block speed below which it counts as still, m/s.
STILL_SPEED = 0.01
#: A broken-tower start: the push starts this far (m) from the struck block's centre and runs this far (m),
#: heading within this angle (rad) of the spawn region's centre.  Pushed outwards, a tower near the region's
#: edge threw blocks past the workspace, where no grasp reaches (the planned agent failed 6 of 20 such starts).
BREAK_PUSH_START, BREAK_PUSH_DISTANCE, BREAK_SPREAD = 0.08, 0.1, np.pi / 3
#: How many towers a broken start builds and pushes at most, and how far (m) above a face-down block's centre
#: height the base's centre may be (higher, it leans on another block).
BREAK_ATTEMPTS, BASE_FLAT_TOLERANCE = 5, 0.003


def blocks_still(cell: Workcell) -> bool:
    """Every block moving slower than ``STILL_SPEED``."""
    return bool(np.all(body_speeds(cell.data, cell.block_ids) < STILL_SPEED))


def holding_a_block(cell: Workcell) -> bool:
    return not cell.robot.bodies_between_fingers().isdisjoint(cell.block_ids.tolist())


@register_task
class TowerBuild(Task):
    """Build a tower of ``n_blocks`` on the base block.

    Options: ``n_blocks`` (2-8, default 4: the base and three to stack; eight
    stand 40 cm); ``order``: ``"any"`` (any colour order above the base) or
    ``"fixed"`` (the scene's colour order: red, green, blue, yellow, lime, cyan,
    purple, magenta); ``tolerance``: how far (m) a block's centre may sit from
    the base's axis (default a fifth of the block); ``block_colours``:
    ``"distinct"`` (default: each block its colour, as in ``order``) or
    ``"uniform"`` (every block the same light grey: only shape and place tell
    blocks apart); ``broken_share``: the share of episodes (0-1, default 0) that
    start from a tower pushed over (``broken_tower``) instead of scattered
    blocks: how BuildAndBreak's later builds start.  ``info`` at reset names
    the base (``base``) and gives its centre (``base_position``, world metres):
    where blocks look alike, that is how an agent knows which one it is.
    Success (primitive modes): all blocks stacked, still and released for 0.5 s.
    Goal-conditioned (low-level modes): goal = where each non-base block stands
    in the finished tower, in the fixed order; success = all within 5 cm.
    Terminates (primitive modes) on success or when a block leaves the table.
    Reward (primitive modes): change in stack height (levels, negative when the
    tower loses blocks), +0.5 the first time each block is grasped from
    outside the tower, +1 on success.
    """

    name = "TowerBuild"
    env_ids = {
        "PandaTowerBuild-v0": EnvId(30),
        # Two blocks, goal-conditioned at 25 Hz: panda-gym's Stack.
        "PandaStack-v0": EnvId(100, {"n_blocks": 2, "action_mode": "ee_delta"}),
    }
    primitives = ("grasp", "place", "push")
    goal_conditioned = True
    start_states = ("in_hand", "above_object")

    def __init__(
        self,
        n_blocks: int = 4,
        order: str = "any",
        tolerance: float | None = None,
        block_colours: str = "distinct",
        broken_share: float = 0.0,
    ) -> None:
        check_tower_blocks(n_blocks)
        check_option("broken_share", broken_share, is_number(broken_share) and 0 <= broken_share <= 1, "in [0, 1]")
        check_option("order", order, order in ("any", "fixed"), "'any' or 'fixed'")
        check_option(
            "tolerance",
            tolerance,
            tolerance is None or (is_number(tolerance) and 0 < tolerance <= 0.025),
            "None or a number in (0, 0.025] m",
        )
        check_block_colours(block_colours)
        self.n_blocks = n_blocks
        self.order = order
        self.tolerance = tolerance
        self.block_colours = block_colours
        self.broken_share = float(broken_share)
        self._stable_since: float | None = None
        self._levels = 1
        self._column: list[int] = [0]
        self._grasp_rewarded: set[str] = set()
        self._goal = np.zeros(3 * (n_blocks - 1))

    def scene_config(self, base: SceneConfig) -> SceneConfig:
        return block_scene(base, self.n_blocks, self.block_colours)

    @property
    def ideal_actions(self) -> int:
        return 2 * (self.n_blocks - 1)

    def reset(self, cell: Workcell, rng: np.random.Generator) -> dict[str, Any]:
        cell.clear()
        # Drawn only when broken starts are asked for: other episodes' scenes are as without the option.
        if self.broken_share > 0 and rng.random() < self.broken_share:
            broken_tower(cell, rng)
        else:
            cell.place_blocks(rng, "scattered")
        cell.settle(0.1)  # blocks start at rest on the table
        size = cell.config.block_size
        base = cell.block_positions()[0]
        self._goal = np.concatenate([base + [0.0, 0.0, size * level] for level in range(1, self.n_blocks)])
        self.restart(cell)
        return {"base": cell.block_names[0], "base_position": base, "stack_height": self._levels}

    def restart(self, cell: Workcell) -> None:
        """Start building from the blocks as they lie now."""
        self._stable_since = None
        self._column = self.column(cell)
        self._levels = len(self._column)
        self._grasp_rewarded: set[str] = set()

    def column(self, cell: Workcell) -> list[int]:
        """Block indices in the column on the base, bottom up (the base first)."""
        order = list(range(self.n_blocks)) if self.order == "fixed" else None
        return stack_column(cell.block_positions(), 0, cell.config.block_size, self.tolerance, order)

    def levels(self, cell: Workcell) -> int:
        """Blocks in the column on the base (the base counts)."""
        return len(self.column(cell))

    def on_control_step(self, cell: Workcell) -> None:
        complete = self.levels(cell) == self.n_blocks and blocks_still(cell) and not holding_a_block(cell)
        if not complete:
            self._stable_since = None
        elif self._stable_since is None:
            self._stable_since = cell.sim_time

    def built(self, cell: Workcell) -> bool:
        """The tower is complete and has stood still, released, for ``STABLE_TIME``."""
        return self._stable_since is not None and cell.sim_time - self._stable_since >= STABLE_TIME - 1e-9

    def evaluate(self, cell: Workcell, result: PrimitiveResult | None) -> TaskStep:
        levels = self.levels(cell)
        info = {"stack_height": levels, "tower_fell": levels < self._levels}
        if result is None:
            reached = bool(goals_reached(self.achieved_goal(cell), self._goal))
            return TaskStep(0.0 if reached else -1.0, reached, False, info)  # as compute_reward
        success = self.built(cell)
        reward = float(levels - self._levels) + (1.0 if success else 0.0)
        # Grasp bonus: once per block and episode, and not for lifting a block off the tower
        # (otherwise grasp-and-put-back would pay forever).
        if result.primitive == "grasp" and result.success and result.object not in self._grasp_rewarded:
            if cell.block_names.index(result.object) not in self._column:
                reward += 0.5
                self._grasp_rewarded.add(result.object)
        self._levels = levels
        self._column = self.column(cell)
        lost = any(cell.is_parked(b) for b in cell.block_ids)
        return TaskStep(reward, success, success or lost, info)

    @property
    def goal_size(self) -> int:
        return 3 * (self.n_blocks - 1)

    def start_object(self, cell: Workcell) -> int:
        """The first block not yet in the tower."""
        return int(cell.block_ids[next(i for i in range(self.n_blocks) if i not in self._column)])

    def achieved_goal(self, cell: Workcell) -> np.ndarray:
        return cell.block_positions()[1:].ravel()

    def desired_goal(self) -> np.ndarray:
        return self._goal.copy()


def broken_tower(cell: Workcell, rng: np.random.Generator) -> None:
    """Lay the blocks out as a break leaves them: a tower of all blocks on the base (block 0; the others above it
    in random order) is pushed at one of the blocks above the base, roughly towards the spawn region's centre
    (``BREAK_SPREAD``), as the falls recorder and BuildAndBreak's breakers push; the arm is home again
    afterwards.  Expects a cleared cell (``TowerBuild.reset`` clears it).  A tower whose base ends up leaning on
    another block (no tower could stand on it) is built and pushed again, up to ``BREAK_ATTEMPTS`` times."""
    n_blocks, size = len(cell.block_ids), cell.config.block_size
    for attempt in range(BREAK_ATTEMPTS):
        if attempt:
            cell.clear()
        positions, yaws = tower_layout(rng, n_blocks, size)
        order = [0, *(1 + rng.permutation(n_blocks - 1))]  # the block at each level, bottom up
        placed = np.empty_like(positions)
        placed[order] = positions[np.argsort(positions[:, 2])]  # the layout's places, bottom up
        cell.set_block_poses(placed, yaws)
        cell.wait(0.1)
        target = cell.block_positions()[order[int(rng.integers(1, n_blocks))]]
        inward = np.arctan2(*(SPAWN_REGION.mean(axis=1) - target[:2])[::-1])
        heading = float(inward + rng.uniform(-BREAK_SPREAD, BREAK_SPREAD))
        along = np.array([np.cos(heading), np.sin(heading)])
        start = target[:2] - BREAK_PUSH_START * along
        push(cell, start[0], start[1], target[2], heading, BREAK_PUSH_DISTANCE)
        cell.wait(0.5)
        if cell.block_positions()[0, 2] < size / 2 + BASE_FLAT_TOLERANCE:  # the base lies on a face
            return
