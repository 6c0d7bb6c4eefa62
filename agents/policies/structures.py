"""Structure agents: build a target structure, or take pieces off one, through the env's primitive actions.

The goal comes from the observation (``desired_goal``: each target's kind, centre and heading).  What stands
where comes from a perceiver (``structure_views``): ``HeightmapPieces`` reads the overhead heightmap,
``OraclePieces`` the true poses in ``achieved_goal``.  Each step the planner

* takes away, top first, a piece that stands in the goal's way: on a target not yet built, or once every
  target holds its piece, anything else in the goal (a removal's pieces, a scaffold);
* else grasps a loose piece for the next target: the lowest target whose supports stand, nearest the robot
  first (``greedy``); the ``lookahead`` planner first checks each such target in a copy of the simulation
  (``sim.stability.what_if``: the piece set there, one second run) and takes the first that stands, and where
  none does, it tries one scaffold: a column of spare props under the far end of the target's piece;
* pushes a scaffold of its own out sideways (``structures.slide_outs``) once what it holds stands without it,
  when nothing is left to place or the next place would stand in the hand's way out (the lookahead leaves
  such places for last);
* with a piece in the hand, places it on its target, or a piece taken away at the free table spot farthest
  from everything.

The hand's closing axis, ~20 cm wide open, is turned off the pieces nearby (``sim.stacking.crowding``).  World
frame, metres, radians.
"""

from __future__ import annotations

from collections import Counter
from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass
from typing import Any, Protocol

import gymnasium as gym
import mujoco
import numpy as np

from panda_grasp_env.agents.policies.base import PrimitiveActionWriter, record_failure
from panda_grasp_env.agents.policies.registry import register_agent, register_baseline
from panda_grasp_env.agents.policies.structure_views import HeightmapPieces, OraclePieces, Seen, SeenPiece, Targets
from panda_grasp_env.model.structures import (
    BLOCK_KINDS,
    TIERS,
    Piece,
    SlideOut,
    grip_headings,
    roomiest,
    slide_outs,
    wrapped,
)
from panda_grasp_env.sim.stability import WhatIf, what_if
from panda_grasp_env.sim.stacking import HAND_REACH, least_crowded
from panda_grasp_env.sim.structure_layout import LOOSE_REACH, LOOSE_REGION
from panda_grasp_env.tasks.structure_build import resting_on

#: How far (metres) the scaffold search puts a prop column under a piece's far end, along its long axis: the
#: rest stands out, for the fingers to push it out later (``structures.slide_outs``).
SCAFFOLD_UNDER = (0.015, 0.01, 0.02)
#: A scaffold of the planner's own is still where it was set when a piece is seen this near (metres): within
#: its half-length, as the heightmap sees only the part standing out from under what it holds, or only the part
#: outside the goal's area as loose.  Pushes that fail to move it are tried ``SLIDE_TRIES`` times.
SCAFFOLD_SEEN, SLIDE_TRIES = BLOCK_KINDS["prop"][0] + 0.005, 2
#: The benchmarks these agents play: the env's own structure, one per tier of the named suite, and its sample.
STRUCTURE_BENCHMARKS = ("Structure", *(f"Structures{tier}" for tier in range(1, len(TIERS) + 1)), "StructuresSample")
#: Most what-if runs one decision may make (each is ~1 s of simulated time): the lookahead's budget.
WHAT_IF_BUDGET = 24


class Verdict(Protocol):
    """What a stability check found: whether everything watched stands."""

    @property
    def stands(self) -> bool: ...


#: A stability check with ``what_if``'s signature: (model, data, moves {body: (position, yaw)}, watched bodies)
#: -> a verdict; the simulator's own (``what_if``) or a learned model's (``learned_physics.FallModelCheck``).
StabilityCheck = Callable[
    [mujoco.MjModel, mujoco.MjData, Mapping[int, tuple[np.ndarray, float]], Sequence[int]], Verdict
]


@dataclass
class _Plan:
    """What the hand's load is for: a target (index) or a drop spot (x, y), the load's kind and its heading
    relative to the closing axis."""

    kind: str
    turn: float
    target: int | None = None
    drop: np.ndarray | None = None
    scaffold: tuple[np.ndarray, float] | None = None


class StructurePlanner:
    """Builds the goal of ``PandaStructure-v0`` (see the module's docstring) with ``perceiver``'s pieces;
    ``lookahead`` checks each place in a copy of ``env``'s simulation first (``env`` is needed only then), with
    ``check``: the simulator's what-if run, or a learned model's prediction of one."""

    def __init__(
        self,
        perceiver: HeightmapPieces | OraclePieces,
        lookahead: bool,
        env: gym.Env | None = None,
        check: StabilityCheck = what_if,
    ) -> None:
        if lookahead and env is None:
            raise ValueError("the lookahead planner needs the env, to copy its simulation")
        self.perceiver, self.lookahead, self.check = perceiver, lookahead, check
        self.cell = env.unwrapped.cell if lookahead else None
        kind = "lookahead" if lookahead else "greedy"
        self.name = f"structure_{kind}_{perceiver.name}"
        self.failures: Counter = Counter()

    def reset(self, observation: Any, info: dict[str, Any]) -> None:
        if not isinstance(observation, dict) or "desired_goal" not in observation:
            raise ValueError(
                f"{self.name} reads the goal from a Dict observation's desired_goal: play PandaStructure-v0"
            )
        self.writer = PrimitiveActionWriter(info, self.name, ("grasp", "place"), needs_z=True)
        self.targets = Targets.of(observation["desired_goal"])
        self.perceiver.reset(observation, info, self.targets, self.name)
        self.plan: _Plan | None = None
        self.holding = False
        #: Scaffold props still to stand: (centre (x, y, z), yaw); those standing: (centre, yaw, pushes tried).
        self.scaffolds: list[tuple[np.ndarray, float]] = []
        self.standing_scaffolds: list[list[Any]] = []
        self.push_distance = float(info["action_layout"].get("push_distance", 0.0))

    # --- acting ---------------------------------------------------------------------
    def act(self, observation: Any, info: dict[str, Any]) -> np.ndarray:
        record_failure(self.failures, info)
        self._track_hand(info)
        seen = self.perceiver(observation)
        if self.holding and self.plan is not None:
            return self._place(seen)
        self.plan = None
        return self._grasp_next(seen)

    def _track_hand(self, info: dict[str, Any]) -> None:
        """Whether the hand holds a piece: after a grasp that succeeded, or a place that could not start."""
        primitive = info.get("primitive")
        if primitive == "grasp":
            self.holding = bool(info["primitive_success"])
        elif primitive == "place":
            self.holding = info["primitive_reason"] in ("unreachable", "out_of_workspace")

    def _grasp_next(self, seen: Seen) -> np.ndarray:
        targets, unfilled = self.targets, ~seen.filled
        # In the way: on a target still to build, or anything left in the goal once it is all built.
        blocking = [
            p
            for p in seen.excess
            if not self._is_own_scaffold(p) and (not unfilled.any() or self._on_unfilled(p, unfilled))
        ]
        if blocking:
            piece = max(blocking, key=lambda p: p.position[2])
            return self._grasp(piece, _Plan(piece.kind, 0.0, drop=self._drop_spot(seen)), seen)
        if self.scaffolds:
            centre, yaw = self.scaffolds[0]
            piece = self._loose_of("prop", centre, seen, keep=self._needed(seen, "prop"))
            if piece is not None:
                self.scaffolds.pop(0)
                self.standing_scaffolds.append([centre, yaw, 0])
                return self._grasp(piece, _Plan("prop", 0.0, scaffold=(centre, yaw)), seen)
            self.scaffolds.clear()  # no spare prop left for it
        ready = [i for i in np.flatnonzero(unfilled) if all(seen.filled[j] for j in targets.supports(int(i)))]
        # Lowest first; among equals, nearest the robot's base (the world's origin) first.
        ready.sort(key=lambda i: (round(targets.bottom(i), 3), float(np.linalg.norm(targets.centres[i, :2]))))
        exits = self._exits(seen)
        ready.sort(key=lambda i: self._blocks_exit(int(i), exits))  # places in a scaffold's way out last
        choice = self._choose(ready, seen) if self.lookahead else (ready[0] if ready else None)
        if self.scaffolds:  # the lookahead found that a scaffold must stand first
            return self._grasp_next(seen)
        if exits and (choice is None or self._blocks_exit(choice, exits)):
            action = self._slide_out(exits, seen)
            if action is not None:
                return action
        if choice is None:
            self.failures["no_candidate"] += 1
            return self._idle()
        piece = self._loose_of(targets.kinds[choice], targets.centres[choice], seen)
        if piece is None:
            self.failures["no_candidate"] += 1
            return self._idle()
        return self._grasp(piece, _Plan(piece.kind, 0.0, target=choice), seen)

    def _on_unfilled(self, piece: SeenPiece, unfilled: np.ndarray) -> bool:
        reach = self.targets.half_extents[:, :2].max(axis=1) + 0.02
        near = np.linalg.norm(self.targets.centres[:, :2] - piece.position[:2], axis=1) < reach
        return bool(np.any(near & unfilled))

    def _is_own_scaffold(self, piece: SeenPiece) -> bool:
        return any(np.linalg.norm(piece.position[:2] - c[:2]) < SCAFFOLD_SEEN for c, _, _ in self.standing_scaffolds)

    def _needed(self, seen: Seen, kind: str) -> int:
        """Pieces of ``kind`` the targets still to build need."""
        return int(sum(1 for i in np.flatnonzero(~seen.filled) if self.targets.kinds[i] == kind))

    def _loose_of(self, kind: str, near: np.ndarray, seen: Seen, keep: int = 0) -> SeenPiece | None:
        """The free piece of ``kind`` nearest ``near``, if more than ``keep`` of them are free: loose, or fallen
        flat on the table in the goal's area (not a scaffold standing)."""
        fallen = [p for p in seen.excess if p.position[2] < p.half_height + 0.005]
        candidates = [p for p in seen.loose + fallen if p.kind == kind and not self._is_own_scaffold(p)]
        if len(candidates) <= keep:
            return None
        return min(candidates, key=lambda p: float(np.linalg.norm(p.position[:2] - near[:2])))

    def _idle(self) -> np.ndarray:
        """An action that does nothing: a place with an empty hand ends at once (``not_holding``)."""
        return self.writer("place", 0.5, 0.0, 0.0, z=0.0)

    def _grasp(self, piece: SeenPiece, plan: _Plan, seen: Seen) -> np.ndarray:
        heading = self._clearest(
            piece.position, grip_headings(piece.kind, piece.yaw), piece.position[2] - piece.half_height, seen, piece
        )
        plan.turn = piece.yaw - heading
        self.plan = plan
        return self.writer("grasp", piece.position[0], piece.position[1], heading, z=piece.position[2])

    def _place(self, seen: Seen) -> np.ndarray:
        plan = self.plan
        if plan.target is not None:
            centre, yaw = self.targets.centres[plan.target], float(self.targets.yaws[plan.target])
            bottom = self.targets.bottom(plan.target)
        elif plan.scaffold is not None:
            (centre, yaw), bottom = plan.scaffold, float(plan.scaffold[0][2]) - BLOCK_KINDS["prop"][2]
        else:
            centre, yaw, bottom = np.array([*plan.drop, 0.0]), 0.0, 0.0
            return self.writer("place", centre[0], centre[1], wrapped(yaw - plan.turn, np.pi), z=bottom)
        hand = yaw - plan.turn
        candidates = [hand, hand + np.pi / 2] if plan.kind == "cube" else [hand]
        if plan.target is not None and plan.kind == "cube":  # a grip the fingers can open, if there is one
            free = self.targets.free_headings(plan.target, seen.filled)
            unblocked = [h for h in candidates if any(abs(wrapped(h - f, np.pi)) < 0.1 for f in free)]
            candidates = unblocked or candidates
        heading = self._clearest(centre, candidates, bottom, seen, None)
        return self.writer("place", centre[0], centre[1], heading, z=bottom)

    def _clearest(
        self, centre: np.ndarray, headings: list[float], height: float, seen: Seen, moving: SeenPiece | None
    ) -> float:
        """Of ``headings``, the one whose closing axis points least at what stands higher than ``height``
        within ``HAND_REACH`` (targets built, pieces seen), within [-pi/2, pi/2)."""
        tops = [
            (c[:2], c[2] + h[2]) for c, h, f in zip(self.targets.centres, self.targets.half_extents, seen.filled) if f
        ]
        tops += [(p.position[:2], p.position[2] + p.half_height) for p in seen.loose + seen.excess if p is not moving]
        obstacles = np.array(
            [xy for xy, top in tops if top > height + 0.001 and 1e-3 < np.linalg.norm(xy - centre[:2]) < HAND_REACH]
        ).reshape(-1, 2)
        return least_crowded(centre, headings, obstacles)

    def _drop_spot(self, seen: Seen) -> np.ndarray:
        """The table point (x, y) within the loose pieces' region and reach farthest from every target and piece."""
        xs, ys = np.meshgrid(np.linspace(*LOOSE_REGION[0], 12), np.linspace(*LOOSE_REGION[1], 16))
        spots = np.stack([xs.ravel(), ys.ravel()], axis=1)
        spots = spots[np.linalg.norm(spots, axis=1) <= LOOSE_REACH]
        occupied = np.array([*self.targets.centres[:, :2], *(p.position[:2] for p in seen.loose + seen.excess)])
        clearance = np.linalg.norm(spots[:, None, :] - occupied[None, :, :], axis=2).min(axis=1)
        return spots[int(np.argmax(clearance))]

    # --- lookahead ------------------------------------------------------------------
    def _choose(self, ready: list[int], seen: Seen) -> int | None:
        """The first of ``ready`` whose piece stands when set on its target now (a what-if run); where none does,
        the first for which a scaffold column makes it stand (queued in ``scaffolds``); else the first."""
        runs = 0
        # Orders that keep every target reachable first: a place that would leave a target still to build with
        # no grip the fingers can open in waits (the square ring's corners go in before the sides between them).
        for index in sorted(ready, key=lambda i: self._pinches(i, seen.filled)):
            if runs >= WHAT_IF_BUDGET:
                break
            runs += 1
            if self._stands(index, seen, []).stands:
                return index
        for index in ready:
            for column in self._scaffold_columns(index, seen):
                if runs >= WHAT_IF_BUDGET:
                    break
                runs += 1
                if self._stands(index, seen, column).stands:
                    self.scaffolds = column
                    return None
        return ready[0] if ready else None

    def _pinches(self, index: int, filled: np.ndarray) -> int:
        """How many targets, target ``index``'s own place among them, the fingers could not open at once it
        stands (with those already ``filled``)."""
        after = filled.copy()
        after[index] = True
        pinched = [i for i in np.flatnonzero(~after) if not self.targets.free_headings(int(i), after)]
        return len(pinched) + (not self.targets.free_headings(index, filled))

    def _bodies(self) -> tuple[np.ndarray, np.ndarray]:
        """The object slots' bodies and their centres now (the simulation's truth, for the what-if runs)."""
        bodies = np.asarray(self.cell.object_ids, dtype=int)
        return bodies, self.cell.data.xpos[bodies]

    def _stands(self, index: int, seen: Seen, column: list[tuple[np.ndarray, float]]) -> Verdict:
        """Set target ``index``'s piece (the loose one the planner would take) and the ``column``'s cubes in a
        copy of the simulation, and run it: does everything built stand?"""
        bodies, centres = self._bodies()
        kind = self.targets.kinds[index]
        moves: dict[int, tuple[np.ndarray, float]] = {}
        free = list(seen.loose)
        for centre, yaw, piece_kind in [(self.targets.centres[index], float(self.targets.yaws[index]), kind)] + [
            (c, y, "prop") for c, y in column
        ]:
            piece = next((p for p in free if p.kind == piece_kind), None)
            if piece is None:
                return WhatIf(np.inf, np.inf, 0.0)
            free.remove(piece)
            body = int(bodies[np.argmin(np.linalg.norm(centres - piece.position, axis=1))])
            moves[body] = (centre, yaw)
        near = np.linalg.norm(centres[:, :2] - self.targets.centres[index, :2], axis=1) < 0.3
        watched = {int(b) for b in bodies[near & (centres[:, 2] > -0.1)]} | set(moves)
        return self.check(self.cell.model, self.cell.data, moves, watched)

    def _scaffold_columns(self, index: int, seen: Seen) -> list[list[tuple[np.ndarray, float]]]:
        """Columns of spare props that could hold target ``index``'s piece up: under its far end (past its
        supports) by ``SCAFFOLD_UNDER``, as high as its bottom, clear of the goal's other targets."""
        targets = self.targets
        levels = int(round(targets.bottom(index) / (2 * BLOCK_KINDS["prop"][2])))
        spare = sum(1 for p in seen.loose if p.kind == "prop") - self._needed(seen, "prop")
        if levels < 1 or spare < levels:
            return []
        yaw, half = float(targets.yaws[index]), targets.half_extents[index, 0]
        axis = np.array([np.cos(yaw), np.sin(yaw)])
        supports = targets.supports(index)
        base = targets.centres[supports, :2].mean(axis=0) if supports else targets.centres[index, :2]
        side = np.sign((targets.centres[index, :2] - base) @ axis) or 1.0  # the overhanging end
        columns = []
        for under in SCAFFOLD_UNDER:
            xy = targets.centres[index, :2] + side * (half + BLOCK_KINDS["prop"][0] - under) * axis
            column = [(np.array([*xy, (2 * k + 1) * BLOCK_KINDS["prop"][2]]), yaw) for k in range(levels)]
            others = [j for j in range(len(targets.kinds)) if j != index and targets.bottom(j) < targets.bottom(index)]
            if any(np.linalg.norm(targets.centres[j, :2] - xy) < 0.05 for j in others):
                continue
            columns.append(column)
        return columns

    # --- scaffolds out -------------------------------------------------------------
    def _exits(self, seen: Seen) -> list[tuple[list[Any], list[SlideOut]]]:
        """The planner's scaffolds still standing where it set them, each with the pushes that slide it out from
        under the built targets resting on it (none: nothing rests on it yet, or the fingers cannot reach)."""
        if "push" not in self.writer.primitives or not self.push_distance:
            return []
        pieces = seen.loose + seen.excess
        built = self.targets.pieces(seen.filled)
        exits = []
        for entry in list(self.standing_scaffolds):
            centre, yaw, tries = entry
            there = any(np.linalg.norm(p.position[:2] - centre[:2]) < SCAFFOLD_SEEN for p in pieces)
            if tries and not there:  # pushed out
                self.standing_scaffolds.remove(entry)
            if tries >= SLIDE_TRIES or not there:
                continue
            prop = Piece("prop", tuple(centre), yaw)
            covers = resting_on(prop, built)
            pushes = slide_outs(prop, covers) if covers else []
            if pushes:
                exits.append((entry, pushes))
        return exits

    def _blocks_exit(self, index: int, exits: list[tuple[list[Any], list[SlideOut]]]) -> bool:
        """Whether target ``index``'s piece would stand where the hand passes pushing a scaffold out (every way
        out of some scaffold)."""
        piece = self.targets.pieces()[index]
        return any(all(push.passes_over(piece, self.push_distance) for push in pushes) for _, pushes in exits)

    def _slide_out(self, exits: list[tuple[list[Any], list[SlideOut]]], seen: Seen) -> np.ndarray | None:
        """The push that takes the first scaffold out which what it holds no longer needs (a what-if run with
        the scaffold moved off to a free spot), on the stroke that ends farthest from the other pieces."""
        bodies, centres = self._bodies()
        drop = self._drop_spot(seen)
        for entry, pushes in exits:
            centre, yaw, _ = entry
            body = int(bodies[np.argmin(np.linalg.norm(centres - centre, axis=1))])
            near = np.linalg.norm(centres[:, :2] - centre[:2], axis=1) < 0.3
            watched = {int(b) for b in bodies[near & (centres[:, 2] > -0.1)]} - {body}
            moves = {body: (np.array([*drop, centre[2]]), yaw)}
            if not self.check(self.cell.model, self.cell.data, moves, watched).stands:
                continue
            others = np.array([c[:2] for b, c in zip(bodies, centres) if b != body and c[2] > -0.1])
            built = self.targets.pieces(seen.filled)
            clear = [p for p in pushes if not any(p.passes_over(piece, self.push_distance) for piece in built)]
            if not clear:
                continue
            push = roomiest(clear, centre, others, self.push_distance)
            entry[2] += 1
            x, y, z = push.start
            return self.writer("push", x, y, push.heading, z=z)
        return None


@register_baseline(*STRUCTURE_BENCHMARKS)
def structure_planner(env: gym.Env, seed: int, oracle: bool) -> StructurePlanner:
    """The structure benchmarks' planned baseline: greedy on the heightmap, or (``oracle``) the lookahead
    planner on the true poses."""
    if oracle:
        return StructurePlanner(OraclePieces(), lookahead=True, env=env)
    return StructurePlanner(HeightmapPieces(), lookahead=False)


@register_agent("planned_lookahead", *STRUCTURE_BENCHMARKS)
def lookahead_planner(env: gym.Env, seed: int) -> StructurePlanner:
    """``planned_lookahead``: the heightmap planner that checks every place in a copy of the simulation."""
    return StructurePlanner(HeightmapPieces(), lookahead=True, env=env)
