"""BuildAndBreak: a continuing task -- build the tower, break it, build it again, ..."""

from __future__ import annotations

from typing import Any

import numpy as np

from panda_grasp_env.model.scene import SceneConfig
from panda_grasp_env.primitives.result import PrimitiveResult
from panda_grasp_env.registration import EnvId, register_task
from panda_grasp_env.sim.workcell import Workcell
from panda_grasp_env.tasks.base import Task, TaskStep
from panda_grasp_env.tasks.tower_break import TowerBreak
from panda_grasp_env.tasks.tower_build import TowerBuild


@register_task
class BuildAndBreak(Task):
    """Alternate TowerBuild and TowerBreak on the same blocks, forever (truncated by the step limit).

    Starts from scattered blocks in the ``build`` phase.  A built tower (all
    ``n_blocks`` stacked on the base, still and released for 0.5 s) counts a
    build and switches to ``break``; knocking ``n_blocks - 1`` blocks out of that
    tower with a successful push counts a break and switches back (a tower a
    failed primitive knocked over switches back without counting).  ``info`` carries ``phase``,
    ``builds`` and ``breaks``; ``is_success`` is true once a full build-and-break
    cycle is complete.  At reset ``info`` also names the base and gives its
    centre (``base``, ``base_position``, as TowerBuild); every build is on that
    block, and the step that starts a new build gives the base's centre again (``base_position``).
    Options: ``n_blocks`` (2-8, default 4) and ``block_colours`` (``"distinct"`` or ``"uniform"``), as
    TowerBuild's.  Reward: the phase's own reward (stack progress while
    building, blocks moved while breaking), +1 per completed phase.  Terminates
    only if a block leaves the table.
    """

    name = "BuildAndBreak"
    env_ids = {"PandaBuildAndBreak-v0": EnvId(100)}
    primitives = ("grasp", "place", "push")

    def __init__(self, n_blocks: int = 4, block_colours: str = "distinct") -> None:
        self.build = TowerBuild(n_blocks=n_blocks, block_colours=block_colours)
        self.breaker = TowerBreak(n_blocks=n_blocks, block_colours=block_colours)
        self.n_blocks = n_blocks
        self.phase = "build"
        self.builds = self.breaks = 0

    def scene_config(self, base: SceneConfig) -> SceneConfig:
        return self.build.scene_config(base)

    @property
    def ideal_actions(self) -> int:
        """Per build-and-break cycle."""
        return self.build.ideal_actions + self.breaker.ideal_actions

    def reset(self, cell: Workcell, rng: np.random.Generator) -> dict[str, Any]:
        build_info = self.build.reset(cell, rng)
        self.phase, self.builds, self.breaks = "build", 0, 0
        return {"base": build_info["base"], "base_position": build_info["base_position"], **self._info(cell)}

    def _info(self, cell: Workcell) -> dict[str, Any]:
        return {"phase": self.phase, "builds": self.builds, "breaks": self.breaks, "cycles": self.breaks}

    def on_control_step(self, cell: Workcell) -> None:
        if self.phase == "build":
            self.build.on_control_step(cell)

    def evaluate(self, cell: Workcell, result: PrimitiveResult | None) -> TaskStep:
        restarted: dict[str, Any] = {}
        if self.phase == "build":
            reward = self.build.evaluate(cell, result).reward if result is not None else 0.0
            if self.build.built(cell):
                self.builds += 1
                self.phase = "break"
                self.breaker.mark_tower(cell)
        else:
            moved, change = self.breaker.newly_moved(cell)
            reward = float(change)
            if moved >= self.breaker.k:  # broken; it counts only if the push that did it succeeded
                if result is not None and result.success:
                    self.breaks += 1
                    reward += 1.0
                self.phase = "build"
                self.build.restart(cell)
                # Where the base lies for the new build, as at reset: blocks may look alike.
                restarted = {"base_position": cell.block_positions()[0].copy()}
        lost = any(cell.is_parked(b) for b in cell.block_ids)
        return TaskStep(reward, self.breaks > 0, lost, self._info(cell) | restarted)
