"""StructureBuild: build a target structure of cubes and planks (``model.structures``), or take pieces off one.

The target is a structure of the named suite (``model.structure_suite``: test-only), a user's ``Structure``
(or its mapping), or ``"random"``: a structure drawn per episode from the motifs of tiers 1-4
(``model.structure_generator``) with random sizes, never one resembling the suite's.  Identical pieces are interchangeable: each
kind's pieces are matched to its targets by the assignment that minimises the total distance (Hungarian).
World frame, metres, radians.
"""

from __future__ import annotations

from typing import Any

import numpy as np
from scipy.optimize import linear_sum_assignment

from panda_grasp_env.geometry import is_count
from panda_grasp_env.model.scene import SceneConfig
from panda_grasp_env.model.structure_generator import GENERATED_TIERS, MAX_PIECES, check_tiers, random_structure
from panda_grasp_env.model.structure_suite import as_structure
from panda_grasp_env.model.structures import (
    BLOCK_KINDS,
    STRUCTURE_PHYSICS,
    Piece,
    Structure,
    footprint_distance,
    footprints_within,
    resting_pose,
    symmetry,
)
from panda_grasp_env.perception.heightmap import HeightmapGrid, heightmap_of_boxes
from panda_grasp_env.primitives.result import PrimitiveResult
from panda_grasp_env.registration import EnvId, register_task
from panda_grasp_env.sim.stepping import body_speeds
from panda_grasp_env.sim.structure_layout import StructureLayout, lay_out_start
from panda_grasp_env.sim.workcell import Workcell
from panda_grasp_env.tasks.base import Task, TaskStep, check_option, with_scene

#: A goal piece is in place within this distance (metres) and turn and tilt (radians) of a target of its kind.
PLACE_TOLERANCE, TURN_TOLERANCE = 0.01, np.deg2rad(10.0)
#: A removed or scaffold piece is away once its centre lies this far (metres) or more from every goal target's
#: footprint (``is_away``): 8 cm from a cube target's centre, straight out from a face.
AWAY_DISTANCE = 0.055
#: The finished structure must stand still (every piece slower than ``STILL_SPEED``, m/s) this long, seconds.
STILL_TIME, STILL_SPEED = 2.0, 0.01
#: The object slots of a random structure's scene unless ``max_pieces`` says otherwise.
DEFAULT_PIECES = 6
#: A goal vector holds this many entries per object slot: centre x, y, z (world metres), the cosine and sine of
#: the heading times the turns that map the piece onto itself (4 for a cube, 2 for a plank: equal for every
#: equivalent heading), the tilt from upright (radians) and the kind (``KIND_CODES``; 0: no piece).
GOAL_FIELDS = 7
#: A piece kind's code in goal vectors.
KIND_CODES = {kind: code for code, kind in enumerate(BLOCK_KINDS, start=1)}


def goal_rows(kinds: list[str], positions: np.ndarray, yaws: np.ndarray, tilts: np.ndarray, slots: int) -> np.ndarray:
    """Goal-vector rows (``slots``, ``GOAL_FIELDS``) of pieces of ``kinds`` at ``positions`` (n, 3) with ``yaws`` and
    ``tilts`` (n,), radians; rows past the pieces are zeros (no piece)."""
    rows = np.zeros((slots, GOAL_FIELDS))
    turns = np.array([2 * np.pi / symmetry(kind) for kind in kinds])
    n = len(kinds)
    rows[:n, 0:3] = positions
    rows[:n, 3], rows[:n, 4] = np.cos(turns * yaws), np.sin(turns * yaws)
    rows[:n, 5] = tilts
    rows[:n, 6] = [KIND_CODES[kind] for kind in kinds]
    return rows


def read_rows(rows: np.ndarray) -> tuple[list[str], np.ndarray, np.ndarray]:
    """The kinds, centres (n, 3, world metres) and headings (n, radians modulo the kind's symmetry) of goal-vector
    rows that each hold a piece: ``goal_rows`` read back."""
    kinds = [list(KIND_CODES)[int(round(code)) - 1] for code in rows[:, 6]]
    turns = np.array([2 * np.pi / symmetry(kind) for kind in kinds]).reshape(-1)
    return kinds, rows[:, :3], np.arctan2(rows[:, 4], rows[:, 3]) / turns


def heading_misses(targets: np.ndarray, pieces: np.ndarray, turns: float) -> np.ndarray:
    """(targets, pieces) radians between each target's and each piece's heading, modulo the kind's symmetry
    (``turns``: 2 pi over it), from goal-vector rows (``goal_rows``) of one kind."""
    cross = targets[:, None, 3] * pieces[None, :, 4] - targets[:, None, 4] * pieces[None, :, 3]
    dot = targets[:, None, 3] * pieces[None, :, 3] + targets[:, None, 4] * pieces[None, :, 4]
    return np.abs(np.arctan2(cross, dot)) / turns


def match_goal(achieved: np.ndarray, desired: np.ndarray) -> tuple[list[tuple[int, int]], float]:
    """Match pieces to targets, given as goal-vector rows (``goal_rows``): each kind's pieces to its targets by
    the assignment of least total distance (Hungarian), preferring pieces within ``PLACE_TOLERANCE``,
    ``TURN_TOLERANCE`` and upright within ``TURN_TOLERANCE``.  Returns the (target row, piece row) pairs so
    matched, and the mean distance (metres) from each target to its assigned piece."""
    pairs, distance = [], 0.0
    targets_of_kind = desired[:, 6].round().astype(int)
    pieces_of_kind = achieved[:, 6].round().astype(int)
    for code in set(targets_of_kind[targets_of_kind > 0]):
        target_rows, pieces = np.flatnonzero(targets_of_kind == code), np.flatnonzero(pieces_of_kind == code)
        targets = desired[target_rows]
        turns = 2 * np.pi / symmetry(list(KIND_CODES)[code - 1])
        ours = achieved[pieces]
        cost = np.linalg.norm(ours[None, :, :3] - targets[:, None, :3], axis=2)
        turn = heading_misses(targets, ours, turns)
        fits = (cost <= PLACE_TOLERANCE) & (turn <= TURN_TOLERANCE) & (ours[None, :, 5] <= TURN_TOLERANCE)
        rows, columns = linear_sum_assignment(np.where(fits, cost, 1.0 + cost))
        distance += float(cost[rows, columns].sum()) + 1.0 * (len(targets) - len(rows))  # a piece short: 1 m
        pairs += [(int(target_rows[r]), int(pieces[c])) for r, c in zip(rows, columns) if fits[r, c]]
    return pairs, distance / max(int((targets_of_kind > 0).sum()), 1)


def _per_goal(achieved_goal: np.ndarray, desired_goal: np.ndarray, score: Any) -> np.ndarray:
    """``score(achieved rows, desired rows)`` for each pair of goal vectors (..., slots * ``GOAL_FIELDS``)."""
    achieved, desired = np.asarray(achieved_goal, dtype=float), np.asarray(desired_goal, dtype=float)
    batch = achieved.shape[:-1]
    pairs = zip(achieved.reshape(-1, achieved.shape[-1]), desired.reshape(-1, desired.shape[-1]))
    values = [score(a.reshape(-1, GOAL_FIELDS), d.reshape(-1, GOAL_FIELDS)) for a, d in pairs]
    return np.asarray(values, dtype=np.float32).reshape(batch)


def placed_reward(achieved: np.ndarray, desired: np.ndarray) -> float:
    """Minus the fraction of the goal's targets that no piece stands in (``match_goal``): 0 once all do."""
    return len(match_goal(achieved, desired)[0]) / max(int((desired[:, 6] > 0).sum()), 1) - 1.0


def is_away(point: np.ndarray, goal: list[Piece]) -> bool:
    """Whether a spare piece whose centre stands at table point ``point`` (x, y) is out of the ``goal``'s way
    (world poses): ``AWAY_DISTANCE`` or more from every goal piece's footprint."""
    return all(footprint_distance(point, piece) >= AWAY_DISTANCE for piece in goal)


def resting_on(piece: Piece, others: list[Piece]) -> list[Piece]:
    """Those of ``others`` (world poses, as ``piece``'s) whose bottom lies on ``piece``'s top within 1 cm and
    whose footprint overlaps its."""
    top = piece.position[2] + piece.half_extents[2]
    return [
        other
        for other in others
        if abs(other.position[2] - other.half_extents[2] - top) < 0.01 and footprints_within(piece, other, 0.0)
    ]


@register_task
class StructureBuild(Task):
    """Build ``structure`` (options below), or take its ``removed`` pieces off it, with the primitives.

    Options: ``structure``: a suite name, a ``Structure`` or its mapping, or ``"random"`` (default: one drawn
    per episode, ``model.structure_generator.random_structure``); ``tiers``: the tiers a random structure's
    motif comes from (one of 1-4 or a list; default all four; only with ``structure="random"``);
    ``max_pieces``: the scene's object slots (2-8; default: the structure's pieces, or 6 for random ones), the
    block budget of a random structure and the most pieces a ``reset(options={"structure": ...})`` one may
    have.

    Goal-conditioned in every action mode: the observation is a ``Dict`` with ``achieved_goal`` (every object
    slot's pose, ``goal_rows``) and ``desired_goal`` (the goal pieces' target poses, padded), and in pixel
    observations ``goal_heightmap``, the goal drawn on the heightmap's grid.  ``compute_reward`` is minus the
    fraction of targets that no piece of their kind stands in (within 1 cm and 10 degrees, upright; identical
    pieces matched optimally, ``match_goal``), vectorised for hindsight relabelling; ``reward_type="dense"``
    adds nothing but distance: minus the mean distance (metres) from each target to its matched piece.

    ``info`` at reset gives ``structure`` (its name), ``tier`` (its suite tier or generated motif's; 0 for a
    user's), ``n_targets`` and the goal pieces' ``targets`` (centres,
    world metres) and ``target_yaws`` (radians), padded with zeros to the scene's object slots; after each step
    ``structure``, ``in_place`` (targets a piece stands in), ``placed_fraction``, ``away`` (removed and scaffold
    pieces out of the goal's way, ``is_away``) and, once something went wrong and until success, ``failure_reason``,
    the episode's last: ``collapsed`` (a piece in place fell out of it), ``lost`` (a piece left the table) or
    ``scaffold_left`` (every target built, a scaffold still in the goal).  Success: every target held by a
    piece, nothing else in the goal's way, nothing held, the pieces still for 2 s (the step waits up to 3 s for
    that once every piece is in place).  Terminates on success or when a piece leaves the table.
    """

    name = "StructureBuild"
    env_ids = {"PandaStructure-v0": EnvId(40)}
    primitives = ("grasp", "place", "push")
    goal_conditioned = True
    goals_in_every_mode = True
    reset_options = ("structure",)

    def __init__(self, structure: Any = "random", max_pieces: int | None = None, tiers: Any = GENERATED_TIERS) -> None:
        try:
            self.fixed = None if isinstance(structure, str) and structure == "random" else as_structure(structure)
        except ValueError as error:
            raise ValueError(f"task option 'structure': {error}") from None
        try:
            self.tiers = check_tiers(tiers)
        except ValueError as error:
            raise ValueError(f"task option 'tiers': {error}") from None
        if self.fixed is not None and self.tiers != GENERATED_TIERS:
            raise ValueError("task option 'tiers' draws random structures: it needs structure='random'")
        fewest = 2 if self.fixed is None else len(self.fixed.kinds)
        valid = max_pieces is None or (is_count(max_pieces) and max(fewest, 2) <= max_pieces <= MAX_PIECES)
        check_option("max_pieces", max_pieces, valid, f"None or an int in [{max(fewest, 2)}, {MAX_PIECES}]")
        default = DEFAULT_PIECES if self.fixed is None else fewest
        self.n_slots = default if max_pieces is None else max_pieces
        self.structure: Structure = self.fixed or random_structure(np.random.default_rng(0), self.n_slots, self.tiers)
        self._episode_structure: Structure | None = None
        self._targets = np.zeros((0, 3))
        self._target_yaws = np.zeros(0)
        self._target_kinds: list[str] = []
        self._slots = np.zeros(0, dtype=int)
        self._placed = 0
        self._failure = ""  # the episode's last named failure
        self._drawn: tuple[HeightmapGrid, np.ndarray] | None = None
        self._still_since: float | None = None
        #: Where this episode's structure stands and its loose pieces lay at the start (set at reset).
        self.layout: StructureLayout | None = None

    def scene_config(self, base: SceneConfig) -> SceneConfig:
        return with_scene(base, n_blocks=0, n_objects=self.n_slots, **STRUCTURE_PHYSICS)

    @property
    def ideal_actions(self) -> int:
        """A grasp and a place per piece moved, and per scaffold piece a grasp, a place and the push that slides
        it out (``structures.slide_outs``)."""
        moved = len(self.structure.removed) if self.structure.prebuilt else len(self.structure.pieces)
        return 2 * moved + 3 * len(self.structure.scaffold)

    @property
    def goal_size(self) -> int:
        return self.n_slots * GOAL_FIELDS

    def apply_reset_options(self, cell: Workcell, options: dict[str, Any]) -> None:
        """``structure``: this episode's structure (a suite name, a ``Structure`` or its mapping) with at most
        ``max_pieces`` pieces; the next episodes go back to the ``structure`` option's."""
        self._episode_structure = None
        if "structure" not in options:
            return
        try:
            structure = as_structure(options["structure"])
        except ValueError as error:
            raise ValueError(f"reset option 'structure': {error}") from None
        if len(structure.kinds) > self.n_slots:
            raise ValueError(
                f"reset option 'structure': {structure.name!r} has {len(structure.kinds)} pieces; this env has "
                f"{self.n_slots} object slots (make it with max_pieces={len(structure.kinds)} or more)"
            )
        self._episode_structure = structure

    def reset(self, cell: Workcell, rng: np.random.Generator) -> dict[str, Any]:
        self.structure = self._episode_structure or self.fixed or random_structure(rng, self.n_slots, self.tiers)
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
        self._target_kinds = [self.structure.pieces[i].kind for i in goal]
        self._slots = cell.object_ids[: len(self.structure.kinds)]
        self._still_since = None
        self._failure = ""
        self._drawn = None  # the goal heightmap, drawn when first asked for
        self._placed = self.in_place(cell)
        # Padded to the scene's slots, so that every episode's info has one shape (vector envs stack it).
        targets, target_yaws = np.zeros((self.n_slots, 3)), np.zeros(self.n_slots)
        targets[: len(self._targets)], target_yaws[: len(self._targets)] = self._targets, self._target_yaws
        return {
            "structure": self.structure.name,
            "tier": self.structure.tier,
            "n_targets": len(self._targets),
            "targets": targets,
            "target_yaws": target_yaws,
        }

    # --- goals ----------------------------------------------------------------------
    def achieved_goal(self, cell: Workcell) -> np.ndarray:
        data, bodies, kinds = cell.data, self._slots, list(self.structure.kinds)
        poses = np.array([resting_pose(kind, data.xmat[body]) for kind, body in zip(kinds, bodies)]).reshape(-1, 2)
        return goal_rows(kinds, data.xpos[bodies], poses[:, 0], poses[:, 1], self.n_slots).ravel()

    def desired_goal(self) -> np.ndarray:
        upright = np.zeros(len(self._targets))
        return goal_rows(self._target_kinds, self._targets, self._target_yaws, upright, self.n_slots).ravel()

    def compute_reward(self, achieved_goal: np.ndarray, desired_goal: np.ndarray, info: Any) -> np.ndarray:
        return _per_goal(achieved_goal, desired_goal, placed_reward)

    def dense_reward(self, achieved_goal: np.ndarray, desired_goal: np.ndarray, info: Any) -> np.ndarray:
        return _per_goal(achieved_goal, desired_goal, lambda a, d: -match_goal(a, d)[1])

    def goal_heightmap(self, grid: HeightmapGrid) -> np.ndarray:
        # Drawn once an episode: observations ask for it every step.
        if self._drawn is None or self._drawn[0] != grid:
            halves = np.array([BLOCK_KINDS[kind] for kind in self._target_kinds]).reshape(-1, 3)
            self._drawn = (grid, heightmap_of_boxes(grid, self._targets, halves, self._target_yaws))
        return self._drawn[1]

    def _matches(self, cell: Workcell) -> tuple[int, set[int]]:
        """How many goal targets a piece of their kind stands in, and the slot indices of those pieces."""
        desired = self.desired_goal().reshape(-1, GOAL_FIELDS)
        pairs, _ = match_goal(self.achieved_goal(cell).reshape(-1, GOAL_FIELDS), desired)
        return len(pairs), {piece for _, piece in pairs}

    def in_place(self, cell: Workcell) -> int:
        """Goal targets a piece of their kind stands in (within ``PLACE_TOLERANCE`` and ``TURN_TOLERANCE``)."""
        return self._matches(cell)[0]

    def _others_away(self, cell: Workcell, used: set[int]) -> bool:
        """Every piece not standing in a target is away from the goal (``is_away``; only where the goal leaves
        pieces over: removal and scaffolds)."""
        spare = [s for s in range(len(self._slots)) if s not in used]
        if len(spare) + len(used) == len(self._targets):
            return True
        goal = [Piece(k, tuple(c), float(y)) for k, c, y in zip(self._target_kinds, self._targets, self._target_yaws)]
        return all(is_away(cell.data.xpos[self._slots[s]][:2], goal) for s in spare)

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
            self._failure = "lost"
        elif placed < self._placed:
            self._failure = "collapsed"
        elif placed == len(self._targets) and not away and self.structure.scaffold:
            self._failure = "scaffold_left"
        if self._failure and not success:
            info["failure_reason"] = self._failure
        reward = placed / len(self._targets) - 1.0  # as compute_reward
        self._placed = placed
        return TaskStep(float(reward), success, success or lost, info)

    def _still_long_enough(self, cell: Workcell) -> bool:
        return self._still_since is not None and cell.sim_time - self._still_since >= STILL_TIME - 1e-9
