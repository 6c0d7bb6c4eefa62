"""StructureBuild: build a target structure of cubes and planks (``model.structures``), or take pieces off one.

The target is a structure of the named suite (``model.structure_suite``: test-only), a user's ``Structure``
(or its mapping), or ``"random"``: a structure drawn per episode from the first three tiers' motifs (a tower,
a row, a bridge) with random sizes, never one of the suite's.  Identical pieces are interchangeable: each
kind's pieces are matched to its targets by the assignment that minimises the total distance (Hungarian).
World frame, metres, radians.
"""

from __future__ import annotations

from typing import Any

import numpy as np
from scipy.optimize import linear_sum_assignment

from panda_grasp_env.geometry import is_count
from panda_grasp_env.model.scene import SceneConfig
from panda_grasp_env.model.structure_suite import PILLAR_OFFSET, as_structure, cube, level, plank
from panda_grasp_env.model.structures import STRUCTURE_PHYSICS, Piece, Structure, symmetry, wrapped
from panda_grasp_env.primitives.result import PrimitiveResult
from panda_grasp_env.registration import EnvId, register_task
from panda_grasp_env.sim.stepping import body_speeds
from panda_grasp_env.sim.structure_layout import StructureLayout, lay_out_start
from panda_grasp_env.sim.workcell import Workcell
from panda_grasp_env.tasks.base import Task, TaskStep, check_option, with_scene

#: A goal piece is in place within this distance (metres) and turn and tilt (radians) of a target of its kind.
PLACE_TOLERANCE, TURN_TOLERANCE = 0.01, np.deg2rad(10.0)
#: A removed or scaffold piece is away at this distance (metres) or more from every goal target.
AWAY_DISTANCE = 0.08
#: The finished structure must stand still (every piece slower than ``STILL_SPEED``, m/s) this long, seconds.
STILL_TIME, STILL_SPEED = 2.0, 0.01
#: The most pieces a random structure has, and the default.
MAX_PIECES, DEFAULT_PIECES = 8, 6


def random_structure(rng: np.random.Generator, max_pieces: int) -> Structure:
    """A structure of at most ``max_pieces`` pieces (>= 2) from the motifs of tiers 1-3, sized at random: a
    tower whose levels shift by up to 4 mm and turn by up to 0.2 rad, a row at a random pitch, or a bridge
    or portal on pillars at a random spacing."""
    motifs = ["tower", "row"] + (["bridge"] if max_pieces >= 3 else [])
    motif = motifs[int(rng.integers(len(motifs)))]
    if motif == "tower":
        n = int(rng.integers(2, min(5, max_pieces) + 1))
        shifts, turns = rng.uniform(-0.004, 0.004, (n, 2)), rng.uniform(-0.2, 0.2, n)
        pieces = tuple(Piece("cube", (*shifts[k], level(k)), turns[k]) for k in range(n))
    elif motif == "row":
        n = int(rng.integers(2, min(4, max_pieces) + 1))
        pitch = rng.uniform(0.058, 0.08)
        pieces = tuple(cube((k - (n - 1) / 2) * pitch, 0.0, 0) for k in range(n))
    else:
        height = int(rng.integers(1, 3)) if max_pieces >= 5 else 1
        offset = rng.uniform(PILLAR_OFFSET - 0.008, PILLAR_OFFSET)
        pillars = tuple(cube(x, 0.0, k) for x in (-offset, offset) for k in range(height))
        pieces = (*pillars, plank(0.0, 0.0, height))
    return Structure(f"random_{motif}", pieces)


@register_task
class StructureBuild(Task):
    """Build ``structure`` (options below), or take its ``removed`` pieces off it, with the primitives.

    Options: ``structure``: a suite name, a ``Structure`` or its mapping, or ``"random"`` (default: one drawn
    per episode, ``random_structure``); ``max_pieces``: the random structures' most pieces (2-8, default 6;
    the scene holds as many object slots).  ``info`` at reset gives ``structure`` (its name), ``n_targets``
    and the goal pieces' ``targets`` (centres, world metres) and ``target_yaws`` (radians), padded with zeros
    to the scene's object slots; after each step ``structure``, ``in_place`` (goal
    pieces within 1 cm and 10 degrees of a target of their kind, identical pieces matched optimally),
    ``placed_fraction``, ``away`` (removed and scaffold pieces 8 cm or more from the goal) and, on failure,
    ``failure_reason``: ``collapsed`` (a piece in place fell out of it), ``lost`` (a piece left the table)
    or ``scaffold_left``.  Success: every goal piece in place, nothing else in the goal's way, nothing held,
    the pieces still for 2 s (the step waits up to 3 s for that once every piece is in place).  Reward: the
    change in the placed fraction, +1 on success.  Terminates on success or when a piece leaves the table.
    """

    name = "StructureBuild"
    env_ids = {"PandaStructure-v0": EnvId(40)}
    primitives = ("grasp", "place", "push")

    def __init__(self, structure: Any = "random", max_pieces: int = DEFAULT_PIECES) -> None:
        valid = is_count(max_pieces) and 2 <= max_pieces <= MAX_PIECES
        check_option("max_pieces", max_pieces, valid, f"an int in [2, {MAX_PIECES}]")
        try:
            self.fixed = None if structure == "random" else as_structure(structure)
        except ValueError as error:
            raise ValueError(f"task option 'structure': {error}") from None
        self.n_slots = max_pieces if self.fixed is None else len(self.fixed.kinds)
        self.structure: Structure = self.fixed or random_structure(np.random.default_rng(0), max_pieces)
        self.max_pieces = max_pieces
        self._targets = np.zeros((0, 3))
        self._target_yaws = np.zeros(0)
        self._slots = np.zeros(0, dtype=int)
        self._placed = 0
        self._still_since: float | None = None
        #: Where this episode's structure stands and its loose pieces lay at the start (set at reset).
        self.layout: StructureLayout | None = None

    def scene_config(self, base: SceneConfig) -> SceneConfig:
        return with_scene(base, n_blocks=0, n_objects=self.n_slots, **STRUCTURE_PHYSICS)

    @property
    def ideal_actions(self) -> int:
        moved = len(self.structure.removed) if self.structure.prebuilt else len(self.structure.pieces)
        return 2 * (moved + 2 * len(self.structure.scaffold))

    def reset(self, cell: Workcell, rng: np.random.Generator) -> dict[str, Any]:
        self.structure = self.fixed or random_structure(rng, self.max_pieces)
        # Slots this structure leaves unused wait parked as cubes: a parked slot's height follows its shape, so
        # the last episode's shape would show in this one's observations.
        unused = cell.object_ids[len(self.structure.kinds) :]
        if len(unused):
            cell.set_object_shapes({int(body): Piece("cube", (0.0, 0.0, 0.025)).shape() for body in unused})
        layout, _ = lay_out_start(cell, self.structure, rng)
        self.layout = layout
        targets, yaws = self.structure.world_poses(layout.origin, layout.heading)
        goal = [i for i in range(len(self.structure.pieces)) if i not in self.structure.removed]
        self._targets, self._target_yaws = targets[goal], yaws[goal]
        self._slots = cell.object_ids[: len(self.structure.kinds)]
        self._still_since = None
        self._placed = self.in_place(cell)
        # Padded to the scene's slots, so that every episode's info has one shape (vector envs stack it).
        targets, target_yaws = np.zeros((self.n_slots, 3)), np.zeros(self.n_slots)
        targets[: len(self._targets)], target_yaws[: len(self._targets)] = self._targets, self._target_yaws
        return {
            "structure": self.structure.name,
            "n_targets": len(self._targets),
            "targets": targets,
            "target_yaws": target_yaws,
        }

    def _matches(self, cell: Workcell) -> tuple[int, set[int]]:
        """How many goal targets a piece of their kind stands in, and the slot indices of those pieces."""
        data, kinds = cell.data, self.structure.kinds
        goal_kinds = [p.kind for p in self.structure.goal]
        placed, used = 0, set()
        for kind in set(goal_kinds):
            targets = [t for t, k in enumerate(goal_kinds) if k == kind]
            pieces = [s for s, k in enumerate(kinds) if k == kind]
            bodies = self._slots[pieces]
            yaws = np.arctan2(data.xmat[bodies][:, 3], data.xmat[bodies][:, 0])
            cost = np.linalg.norm(data.xpos[bodies][None, :, :] - self._targets[targets][:, None, :], axis=2)
            turn = np.abs(wrapped(yaws[None, :] - self._target_yaws[targets][:, None], symmetry(kind)))
            tilt = np.arccos(np.clip(data.xmat[bodies][:, 8], -1.0, 1.0))[None, :]
            fits = (cost <= PLACE_TOLERANCE) & (turn <= TURN_TOLERANCE) & (tilt <= TURN_TOLERANCE)
            rows, columns = linear_sum_assignment(np.where(fits, cost, 1.0 + cost))
            for row, column in zip(rows, columns):
                if fits[row, column]:
                    placed += 1
                    used.add(pieces[column])
        return placed, used

    def in_place(self, cell: Workcell) -> int:
        """Goal targets a piece of their kind stands in (within ``PLACE_TOLERANCE`` and ``TURN_TOLERANCE``)."""
        return self._matches(cell)[0]

    def _others_away(self, cell: Workcell, used: set[int]) -> bool:
        """Every piece not standing in a target lies ``AWAY_DISTANCE`` or more from every goal target (only
        where the goal leaves pieces over: removal and scaffolds)."""
        spare = [s for s in range(len(self._slots)) if s not in used]
        if len(spare) + len(used) == len(self._targets):
            return True
        return all(
            np.linalg.norm(self._targets[:, :2] - cell.data.xpos[self._slots[s]][:2], axis=1).min() >= AWAY_DISTANCE
            for s in spare
        )

    def on_control_step(self, cell: Workcell) -> None:
        moving = body_speeds(cell.data, self._slots) >= STILL_SPEED
        if moving.any() or cell.robot.bodies_between_fingers():
            self._still_since = None
        elif self._still_since is None:
            self._still_since = cell.sim_time

    def evaluate(self, cell: Workcell, result: PrimitiveResult | None) -> TaskStep:
        placed, used = self._matches(cell)
        if placed == len(self._targets) and self._others_away(cell, used):
            # The last action may have just let go: give the structure its still time, at most a second over.
            waited = 0.0
            while not self._still_long_enough(cell) and waited < STILL_TIME + 1.0:
                cell.wait(0.2)
                waited += 0.2
            placed, used = self._matches(cell)
        away = self._others_away(cell, used)
        success = placed == len(self._targets) and away and self._still_long_enough(cell)
        lost = any(cell.is_parked(b) for b in self._slots)
        info: dict[str, Any] = {
            "structure": self.structure.name,
            "in_place": placed,
            "placed_fraction": placed / len(self._targets),
            "away": away,
        }
        if lost:
            info["failure_reason"] = "lost"
        elif placed < self._placed:
            info["failure_reason"] = "collapsed"
        elif placed == len(self._targets) and not away and self.structure.scaffold:
            info["failure_reason"] = "scaffold_left"
        reward = (placed - self._placed) / len(self._targets) + (1.0 if success else 0.0)
        self._placed = placed
        return TaskStep(float(reward), success, success or lost, info)

    def _still_long_enough(self, cell: Workcell) -> bool:
        return self._still_since is not None and cell.sim_time - self._still_since >= STILL_TIME - 1e-9
