"""TowerBreak: a tower of N blocks stands; knock at least k of them out of their tower position."""

from __future__ import annotations

from typing import Any

import numpy as np

from panda_grasp_env.primitives import PrimitiveResult
from panda_grasp_env.scene import SceneConfig
from panda_grasp_env.tasks.base import Task, TaskStep, check_option, is_number, register_task, with_scene
from panda_grasp_env.workcell import Workcell


def blocks_moved(positions: np.ndarray, tower_positions: np.ndarray, block_size: float) -> int:
    """Blocks whose centre is at least one block size from where it stood in the tower."""
    return int(np.sum(np.linalg.norm(positions - tower_positions, axis=1) >= block_size))


@register_task
class TowerBreak(Task):
    """Break a standing tower of ``n_blocks``.

    Options: ``n_blocks`` (2-4, default 4); ``k``: blocks that must leave their
    tower position (moved >= one block size; default all but the base);
    ``allow_impulse``: add the ``impulse`` primitive (a horizontal impulse of
    ``impulse_magnitude`` N s on the block nearest the chosen point, as in the
    fall-dynamics study) next to ``push``.
    Success: >= k blocks moved by a primitive that succeeded; terminates once
    >= k blocks moved (``info["broken_by_failure"]`` when a failed primitive
    moved them: no success).  Reward: blocks newly moved this step, +1 on
    success.
    """

    name = "TowerBreak"
    primitives = ("push",)

    def __init__(
        self, n_blocks: int = 4, k: int | None = None, allow_impulse: bool = False, impulse_magnitude: float = 0.06
    ) -> None:
        check_option("n_blocks", n_blocks, isinstance(n_blocks, int) and 2 <= n_blocks <= 4, "an int in [2, 4]")
        k = n_blocks - 1 if k is None else k
        check_option("k", k, isinstance(k, int) and 1 <= k <= n_blocks, f"an int in [1, {n_blocks}]")
        check_option("allow_impulse", allow_impulse, isinstance(allow_impulse, bool), "a bool")
        valid = is_number(impulse_magnitude) and 0 < impulse_magnitude <= 1.0
        check_option("impulse_magnitude", impulse_magnitude, valid, "in (0, 1] N s")
        self.n_blocks, self.k = n_blocks, k
        self.impulse_magnitude = float(impulse_magnitude)
        self.primitives = ("push", "impulse") if allow_impulse else ("push",)
        self._tower = np.zeros((n_blocks, 3))
        self._moved = 0

    def scene_config(self, base: SceneConfig) -> SceneConfig:
        return with_scene(base, n_blocks=self.n_blocks, n_objects=0)

    @property
    def ideal_actions(self) -> int:
        return 1

    def reset(self, cell: Workcell, rng: np.random.Generator) -> dict[str, Any]:
        cell.clear()
        cell.place_blocks(rng, "tower")
        cell.settle(0.3)
        self.mark_tower(cell)
        return {"blocks_moved": 0}

    def mark_tower(self, cell: Workcell) -> None:
        """Remember the blocks' current positions as the tower to break."""
        self._tower = cell.block_positions()
        self._moved = 0

    def newly_moved(self, cell: Workcell) -> tuple[int, int]:
        """(blocks moved out of the tower so far, how many of them moved since the last call)."""
        moved = blocks_moved(cell.block_positions(), self._tower, cell.config.block_size)
        change, self._moved = moved - self._moved, moved
        return moved, change

    def evaluate(self, cell: Workcell, result: PrimitiveResult | None) -> TaskStep:
        moved, change = self.newly_moved(cell)
        broken = moved >= self.k
        # Only a primitive that did what it reports breaks a tower; one knocked over by a failed push
        # (unreachable, collision) is lost, not broken: the episode ends without success.
        success = broken and result is not None and result.success
        info = {"blocks_moved": moved, "broken_by_failure": broken and not success}
        return TaskStep(float(change) + (1.0 if success else 0.0), success, broken, info)
