"""Oracle tower scripts: build a tower and push it over using the simulator's true block poses.

*Oracle*: these read ground truth from the :class:`~panda_grasp_env.workcell.Workcell`
instead of perceiving it, so their failures are the primitives' failures, not
perception's.  They are the reference the perception-based agents are measured
against, and the demo of the simulation core.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from panda_grasp_env.primitives import PrimitiveResult, grasp, place, push
from panda_grasp_env.stacking import clearest_grasp_heading, tower_footprint_centre, tower_is_built, wrap_quarter_turn
from panda_grasp_env.tasks.tower_break import BREAK_DIRECTIONS
from panda_grasp_env.workcell import Workcell


@dataclass
class TowerOutcome:
    success: bool
    base: str
    #: Primitive results in order (3 grasps + 3 places for an ideal 4-block build).
    steps: list[PrimitiveResult] = field(default_factory=list)
    #: Worst yaw misalignment of a block against the base, degrees (modulo 90).
    max_yaw_error_deg: float = float("nan")


def build_tower(cell: Workcell) -> TowerOutcome:
    """Stack every block on the one nearest the workspace centre, yaw-aligned to it."""
    positions = cell.block_positions()
    base = int(np.argmin(np.linalg.norm(positions[:, :2] - [0.5, 0.0], axis=1)))
    base_xy, base_yaw = positions[base, :2].copy(), float(cell.block_yaws()[base])
    outcome = TowerOutcome(success=False, base=cell.block_names[base])
    stacked = [base]
    for index in (i for i in range(len(positions)) if i != base):
        position = cell.block_positions()[index]
        result = grasp(
            cell, *position, clearest_grasp_heading(cell.block_positions(), index, float(cell.block_yaws()[index]))
        )
        outcome.steps.append(result)
        if not result.success:
            return outcome
        # Turn the hand so the held block's yaw matches the base's (modulo 90 degrees).
        held_relative_yaw = float(wrap_quarter_turn(cell.block_yaws()[index] - cell.robot.ee_yaw))
        top = cell.block_positions()[stacked, 2].max() + cell.config.block_size / 2
        result = place(cell, base_xy[0], base_xy[1], top, base_yaw - held_relative_yaw)
        outcome.steps.append(result)
        if not result.success:
            return outcome
        stacked.append(index)
    outcome.max_yaw_error_deg = float(np.degrees(np.abs(wrap_quarter_turn(cell.block_yaws() - base_yaw))).max())
    outcome.success = tower_is_built(cell.block_positions(), base, cell.config.block_size)
    return outcome


def push_tower(cell: Workcell, direction: str, distance: float = 0.16) -> PrimitiveResult:
    """Push the standing tower with the closed gripper at mid-height, towards ``direction`` (one of BREAK_DIRECTIONS)."""
    if direction not in BREAK_DIRECTIONS:
        raise ValueError(f"unknown push direction {direction!r}; valid: {list(BREAK_DIRECTIONS)}")
    centre = tower_footprint_centre(cell.block_positions())
    heading = BREAK_DIRECTIONS[direction]
    unit = np.array([np.cos(heading), np.sin(heading)])
    start = centre - unit * (cell.config.block_size / 2 + 0.04)
    height = min(cell.block_positions()[:, 2].max() / 2 + 0.01, 0.12)
    return push(cell, start[0], start[1], height, heading, distance)
