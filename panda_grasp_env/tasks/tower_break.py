"""TowerBreak: a tower of N blocks stands; knock at least k of them out of their tower position."""

from __future__ import annotations

from typing import Any

import numpy as np

from panda_grasp_env.geometry import is_count, is_number
from panda_grasp_env.model.scene import SceneConfig
from panda_grasp_env.primitives.result import PrimitiveResult
from panda_grasp_env.registration import EnvId, register_task
from panda_grasp_env.sim.workcell import Workcell
from panda_grasp_env.tasks.base import (
    Task,
    TaskStep,
    block_scene,
    check_block_colours,
    check_option,
    check_tower_blocks,
)

#: The source study's four push directions, as headings about world z (radians).
BREAK_DIRECTIONS = {"+x": 0.0, "+y": np.pi / 2, "-x": np.pi, "-y": -np.pi / 2}


def blocks_moved(positions: np.ndarray, tower_positions: np.ndarray, block_size: float) -> int:
    """Blocks whose centre is at least one block size from where it stood in the tower."""
    return int(np.sum(np.linalg.norm(positions - tower_positions, axis=1) >= block_size))


@register_task
class TowerBreak(Task):
    """Break a standing tower of ``n_blocks``.

    Options: ``n_blocks`` (2-8, default 4); ``k``: blocks that must leave their
    tower position (moved >= one block size; default all but the base);
    ``allow_impulse``: add the ``impulse`` primitive (a horizontal impulse of
    ``impulse_magnitude`` N s on the block nearest the chosen point, as in the
    fall-dynamics study) next to ``push``; ``directional``: the source study's
    directional break -- each episode commands one of ``BREAK_DIRECTIONS``
    (drawn at reset, observed as the one-hot ``command``, in that order), and
    the tower must also fall towards it: the blocks' centroid moves at least one
    block size, within 45 degrees of the commanded heading; ``block_colours``:
    ``"distinct"`` (default) or ``"uniform"`` (every block the same light grey).
    Success: >= k blocks moved by a primitive that succeeded; terminates once
    >= k blocks moved (``info["broken_by_failure"]`` when a failed primitive
    moved them: no success).  Reward: blocks newly moved this step, +1 on
    success.
    """

    name = "TowerBreak"
    env_ids = {
        "PandaTowerBreak-v0": EnvId(5),
        "PandaTowerBreakDirectional-v0": EnvId(5, {"directional": True}),
    }
    primitives = ("push",)

    def __init__(
        self,
        n_blocks: int = 4,
        k: int | None = None,
        allow_impulse: bool = False,
        impulse_magnitude: float = 0.06,
        directional: bool = False,
        block_colours: str = "distinct",
    ) -> None:
        check_tower_blocks(n_blocks)
        k = n_blocks - 1 if k is None else k
        check_option("k", k, is_count(k) and 1 <= k <= n_blocks, f"an int in [1, {n_blocks}]")
        check_option("allow_impulse", allow_impulse, isinstance(allow_impulse, bool), "a bool")
        valid = is_number(impulse_magnitude) and 0 < impulse_magnitude <= 1.0
        check_option("impulse_magnitude", impulse_magnitude, valid, "in (0, 1] N s")
        check_option("directional", directional, isinstance(directional, bool), "a bool")
        check_block_colours(block_colours)
        self.block_colours = block_colours
        self.n_blocks, self.k, self.directional = n_blocks, k, directional
        self.command_size = len(BREAK_DIRECTIONS) if directional else 0
        self.direction = 0  # index into BREAK_DIRECTIONS
        self.impulse_magnitude = float(impulse_magnitude)
        self.primitives = ("push", "impulse") if allow_impulse else ("push",)
        self._tower = np.zeros((n_blocks, 3))
        self._moved = 0

    def scene_config(self, base: SceneConfig) -> SceneConfig:
        return block_scene(base, self.n_blocks, self.block_colours)

    @property
    def ideal_actions(self) -> int:
        return 1

    def reset(self, cell: Workcell, rng: np.random.Generator) -> dict[str, Any]:
        cell.clear()
        cell.place_blocks(rng, "tower")
        cell.settle(0.3)
        self.mark_tower(cell)
        info: dict[str, Any] = {"blocks_moved": 0}
        if self.directional:
            self.direction = int(rng.integers(len(BREAK_DIRECTIONS)))
            info["direction"] = list(BREAK_DIRECTIONS)[self.direction]
        return info

    def command(self) -> np.ndarray:
        """One-hot of the commanded direction (directional breaks), in ``BREAK_DIRECTIONS`` order."""
        return np.eye(len(BREAK_DIRECTIONS), dtype=np.float32)[self.direction]

    def fell_towards_command(self, cell: Workcell) -> bool:
        """The blocks' centroid moved >= one block size within 45 degrees of the commanded heading."""
        shift = (cell.block_positions() - self._tower).mean(axis=0)[:2]
        heading = list(BREAK_DIRECTIONS.values())[self.direction]
        along = float(shift @ [np.cos(heading), np.sin(heading)])
        return float(np.hypot(*shift)) >= cell.config.block_size and along >= np.cos(np.pi / 4) * np.hypot(*shift)

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
        if self.directional:
            info["direction"] = list(BREAK_DIRECTIONS)[self.direction]
            info["wrong_direction"] = success and not self.fell_towards_command(cell)
            success = success and not info["wrong_direction"]
        return TaskStep(float(change) + (1.0 if success else 0.0), success, broken, info)
