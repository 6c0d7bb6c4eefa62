"""Tower agents and scripts: build a tower, and break it with a push.

The tower agents perceive blocks in the env's depth images (``DepthBlocks``: by shape, colour not read, so
all blocks may look alike; ``CameraBlocks`` finds blocks by colour, for tasks that name one by its colour) --
or, in the ``Oracle*`` variants, read the simulator's true block poses -- and act through the env's
``primitive`` action mode.  ``build_tower`` and ``push_tower`` are the same skills as scripts on true poses
(the demo of the simulation core and the primitive benchmarks), whose failures are the primitives' own;
they act through ``env.step`` (``through_env``: the demo) or, to measure the primitives alone, straight on
a workcell (``on_workcell``: the primitive benchmarks).  World frame, metres, radians.
"""

from __future__ import annotations

import functools
from collections import Counter
from collections.abc import Callable
from dataclasses import dataclass, field
from typing import Any

import gymnasium as gym
import numpy as np

from panda_grasp_env.agents.policies.base import CameraViews, PrimitiveActionWriter, record_failure, require
from panda_grasp_env.agents.policies.registry import BaselineFactory, register_baseline
from panda_grasp_env.perception.pose import (
    detect_towers,
    estimate_block_poses,
    estimate_block_poses_from_depth,
    follow_blocks,
    wrap_quarter,
)
from panda_grasp_env.primitives.parameters import (
    GraspParameters,
    PlaceParameters,
    PushParameters,
    TopDownParameters,
)
from panda_grasp_env.primitives.registry import run
from panda_grasp_env.primitives.result import PrimitiveResult
from panda_grasp_env.sim.stacking import (
    clearest_grasp_heading,
    tower_footprint_centre,
    tower_is_built,
    wrap_quarter_turn,
)
from panda_grasp_env.sim.workcell import Workcell
from panda_grasp_env.tasks.tower_break import BREAK_DIRECTIONS

#: Where a push starts: this far from the tower's axis (half a block plus a finger's clearance).
PUSH_START = 0.065
#: Where a push at a tower whose top stands above ``TALL_TOWER_TOP`` starts.  The arm's wrist (link 7, from
#: about 14 cm above the grasp site) reaches 4.5 cm ahead of it: coming down to a push (at most 12 cm high,
#: ``PUSH_HEIGHT_RANGE``) 6.5 cm from a 30 cm tower's axis, it touches the top block and the push stops with
#: ``"collision"`` (measured on TowerBreak6); from 8.5 cm it clears, and the stroke's last centimetres strike
#: the tower with the fingers and the wrist together.
TALL_PUSH_START = 0.085
#: Tower top (metres) above which the wrist passes the tower's upper blocks on the way down (a 4-block
#: tower's top stands at 20 cm, a 5-block one's at 25 cm).
TALL_TOWER_TOP = 0.22


@dataclass(frozen=True)
class SeenBlock:
    """A block as a pose source sees it: centre (world, metres) and yaw (radians about world z)."""

    position: np.ndarray
    yaw: float


class CameraBlocks:
    """Block poses from the overhead and front cameras' RGB-D (with the Kinect-like noise if seeded), each block
    found and named by its colour (``estimate_block_poses``): for tasks that name a block by its colour."""

    name = "camera"

    def __init__(self, noise_seed: int | None = 0) -> None:
        self.noise_seed = noise_seed

    def reset(self, observation: Any, info: dict[str, Any], agent: str) -> None:
        require(info, ("block_colours", "block_size"), agent, "use a tower task of panda_grasp_env")
        self.colours, self.block_size = info["block_colours"], info["block_size"]
        self.views = CameraViews(observation, info, agent, ("overhead", "front"), self.noise_seed)

    def __call__(self, observation: Any) -> dict[str, SeenBlock]:
        poses = estimate_block_poses(self.views(observation), self.colours, self.block_size)
        return {name: SeenBlock(p.position, p.yaw) for name, p in poses.items()}


class DepthBlocks:
    """Block poses from the overhead and front cameras' depth (with the Kinect-like noise if seeded), by shape
    alone (``estimate_block_poses_from_depth``): colour is not read, so blocks may all look alike.  Blocks rest
    on the table or on each other and nothing else stands on the table (a task's fixtures would look like
    blocks): the tower tasks.

    A block keeps its name from one call to the next by geometry alone (``follow_blocks``: it continues the
    known block it lies nearest); a block not seen (in the hand) keeps its last place until it is seen again.
    At reset the block nearest the task's ``base_position`` takes the base's name (``base``); the others are
    ``block_<i>`` in the order first seen.  Its ``name`` is ``camera``, as ``CameraBlocks``'s: perception from
    the cameras, as against the oracle's.
    """

    name = "camera"

    def __init__(self, noise_seed: int | None = 0) -> None:
        self.noise_seed = noise_seed

    def reset(self, observation: Any, info: dict[str, Any], agent: str) -> None:
        require(info, ("block_size",), agent, "use a tower task of panda_grasp_env")
        self.block_size = info["block_size"]
        self.views = CameraViews(observation, info, agent, ("overhead", "front"), self.noise_seed)
        #: Name -> where that block was last seen (centre, world metres).
        self.known: dict[str, np.ndarray] = {}
        if "base" in info and "base_position" in info:
            self.known[info["base"]] = np.asarray(info["base_position"], dtype=float)

    def __call__(self, observation: Any) -> dict[str, SeenBlock]:
        seen = estimate_block_poses_from_depth(self.views(observation), self.block_size)
        blocks = {}
        for block, name in zip(seen, follow_blocks(self.known, seen)):
            if name is None:
                name = next(f"block_{i}" for i in range(len(self.known) + 1) if f"block_{i}" not in self.known)
            self.known[name] = block.position
            blocks[name] = SeenBlock(block.position, block.yaw)
        return blocks


class OracleBlocks:
    """*Oracle*: the simulator's true block poses (reads the env, not the observation)."""

    name = "oracle"

    def __init__(self, env: gym.Env) -> None:
        self.cell = env.unwrapped.cell

    def reset(self, observation: Any, info: dict[str, Any], agent: str) -> None:
        require(info, ("block_size",), agent, "use a tower task of panda_grasp_env")
        self.block_size = info["block_size"]

    def __call__(self, observation: Any) -> dict[str, SeenBlock]:
        positions, yaws = self.cell.block_positions(), self.cell.block_yaws()
        return {
            name: SeenBlock(positions[i], float(wrap_quarter(yaws[i])))
            for i, name in enumerate(self.cell.block_names)
            if positions[i, 2] > -0.1
        }


#: What the tower agents perceive blocks with (each has ``name``, ``block_size``, ``reset`` and a call giving
#: the blocks seen, by name).
BlockPerceiver = CameraBlocks | DepthBlocks | OracleBlocks


class TowerBuilderAgent:
    """Stack every block on the base block, yaw-aligned to it: grasp the clearest loose block, place it on top.

    Each block is aimed at the base's axis as perceived now (the place's height is the env's: the surface
    there), not at the block below: a place lands 1-2 mm off its aim, always the same way, so aiming at the
    top of the tower carried that offset up -- eight blocks on seeds 3-5 stood 14-17 mm off the base's axis
    at the top, past the task's 1 cm -- while aiming at the base's axis left every level within 2.1 mm of it.

    Two recoveries keep a long BuildAndBreak going.  Colour-blind perception can hand the base's name to
    another block when a break leaves the blocks in a touching row: when a build starts (``base_position`` in
    ``info``), or when the base is not among the blocks seen, the block seen nearest where the base lies (or
    was last seen) becomes the base.  If every block seen is in the tower
    and the env still has not called it built one action later, the tower is off (a block beyond the task's
    tolerance): its top block is taken off and placed again.

    Needs ``action_mode='primitive'`` and, with camera perception, ``obs_mode='rgbd'``
    with ``cameras=('overhead', 'front')`` at 640 x 480.
    """

    def __init__(self, perceiver: BlockPerceiver | None = None) -> None:
        self.perceiver = perceiver or DepthBlocks()
        self.name = f"tower_builder_{self.perceiver.name}"
        self.failures: Counter[str] = Counter()

    def reset(self, observation: Any, info: dict[str, Any]) -> None:
        require(info, ("base",), self.name, "use PandaTowerBuild-v0 or PandaBuildAndBreak-v0")
        self.write = PrimitiveActionWriter(info, self.name, ("grasp", "place"))
        self.perceiver.reset(observation, info, self.name)
        self.base = info["base"]
        #: Where the base was last seen (world, metres), or None before it is seen.
        self.base_seen_at: np.ndarray | None = None
        self.held: tuple[str, float] | None = None  # name, block yaw relative to the closing axis
        self.pending: tuple[str, float, float] | None = None
        self.waited = False  # the last action waited for the env's verdict on a tower with no block loose
        self.failures = Counter()

    def observe(self, info: dict[str, Any]) -> None:
        """Take in the last step's outcome (what is in the hand), even if another agent chose that step."""
        record_failure(self.failures, info)
        if info.get("tower_fell"):
            self.failures["tower_fell"] += 1
        if self.pending is not None and info.get("primitive") == "grasp":
            self.held = (self.pending[0], self.pending[1]) if info["primitive_success"] else None
        elif info.get("primitive") in ("place", "push"):
            self.held = None  # a place releases; a push starts with the hand closed on nothing
        self.pending = None

    def act(self, observation: Any, info: dict[str, Any]) -> np.ndarray:
        self.observe(info)
        blocks = self.perceiver(observation)
        if "base_position" in info:  # a build starts (BuildAndBreak's after each break): the base lies there
            self.base_seen_at = np.asarray(info["base_position"], dtype=float)
        if (self.base not in blocks or "base_position" in info) and blocks and self.base_seen_at is not None:
            self.base = min(blocks, key=lambda n: float(np.linalg.norm(blocks[n].position - self.base_seen_at)))
        if self.base not in blocks:
            self.failures["no_candidate"] += 1
            return self.write("grasp", 0.5, 0.0, 0.0, 0.02)  # nothing sensible: a harmless miss
        base = blocks[self.base]
        self.base_seen_at = base.position
        waited, self.waited = self.waited, False
        if self.held is not None:
            _, relative_yaw = self.held
            return self.write("place", base.position[0], base.position[1], base.yaw - relative_yaw, None)
        tower = next(
            (
                t
                for t in detect_towers({n: b.position for n, b in blocks.items()}, self.perceiver.block_size)
                if self.base in t
            ),
            [],
        )
        loose = [name for name in blocks if name not in tower]
        if not loose and (not waited or len(tower) < 2):  # everything stacked: wait for the env's verdict
            self.failures["no_candidate"] += 1
            self.waited = True
            return self.write("grasp", 0.3, 0.3, 0.0, 0.02)
        names = list(blocks)
        positions = np.array([blocks[n].position for n in names])
        if loose:
            target = min(loose, key=lambda n: np.linalg.norm(blocks[n].position[:2] - base.position[:2]))
        else:  # the tower stood a whole action and is not built: take its top block off to place it again
            target = tower[-1]
        heading = clearest_grasp_heading(positions, names.index(target), blocks[target].yaw)
        self.pending = (target, float(wrap_quarter(blocks[target].yaw - heading)), heading)
        block = blocks[target]
        return self.write("grasp", block.position[0], block.position[1], heading, block.position[2])


class TowerBreakerAgent:
    """Push the tallest tower over: of the four directions, the one heading most towards the middle of
    the workspace (so the blocks stay within reach) whose start is clear of other blocks; in a directional
    break (the observation's one-hot ``command``), the commanded one.

    A tower taller than ``TALL_TOWER_TOP`` is pushed from ``TALL_PUSH_START``, and only from a start no
    farther from the robot's base (the world origin) than the tower: from beyond it, the forearm (links 5
    and 6, 20-30 cm above the hand) reaches over the tower's top on the way down.  On TowerBreak8 that rule
    told the 6 of 12 (seed, direction) pairs that collided from the 6 that pushed (seeds 6000003-05)."""

    def __init__(self, perceiver: BlockPerceiver | None = None) -> None:
        self.perceiver = perceiver or DepthBlocks()
        self.name = f"tower_breaker_{self.perceiver.name}"
        self.failures: Counter[str] = Counter()

    def reset(self, observation: Any, info: dict[str, Any]) -> None:
        self.write = PrimitiveActionWriter(info, self.name, ("push",))
        self.perceiver.reset(observation, info, self.name)
        self.failures = Counter()

    def act(self, observation: Any, info: dict[str, Any]) -> np.ndarray:
        record_failure(self.failures, info)
        blocks = self.perceiver(observation)
        towers = detect_towers({n: b.position for n, b in blocks.items()}, self.perceiver.block_size)
        if not towers:
            self.failures["no_candidate"] += 1
            return self.write("push", 0.3, 0.3, 0.0)
        tower = max(towers, key=len)
        centre = blocks[tower[0]].position[:2]
        top = max(blocks[name].position[2] for name in tower) + self.perceiver.block_size / 2
        tall = top > TALL_TOWER_TOP
        start_distance = TALL_PUSH_START if tall else PUSH_START
        others = np.array([blocks[n].position[:2] for n in blocks if n not in tower]).reshape(-1, 2)
        inward = np.array([0.5, 0.0]) - centre
        headings = list(BREAK_DIRECTIONS.values())
        if isinstance(observation, dict) and "command" in observation:
            headings = [headings[int(np.argmax(observation["command"]))]]
        for heading in sorted(headings, key=lambda h: -(np.cos(h) * inward[0] + np.sin(h) * inward[1])):
            direction = np.array([np.cos(heading), np.sin(heading)])
            start = centre - start_distance * direction
            clear = len(others) == 0 or np.min(np.linalg.norm(others - start, axis=1)) > 0.06
            clear = clear and not (tall and np.linalg.norm(start) > np.linalg.norm(centre))
            if clear and 0.27 < start[0] < 0.73 and abs(start[1]) < 0.33:
                return self.write("push", start[0], start[1], heading)
        start = centre - start_distance * np.array([np.cos(headings[0]), np.sin(headings[0])])
        return self.write("push", start[0], start[1], headings[0])


class BuildAndBreakAgent:
    """Builds while the task's phase is ``build`` and pushes the tower over while it is ``break``."""

    def __init__(self, perceiver: BlockPerceiver | None = None) -> None:
        perceiver = perceiver or DepthBlocks()
        self.builder, self.breaker = TowerBuilderAgent(perceiver), TowerBreakerAgent(perceiver)
        self.name = f"build_and_break_{perceiver.name}"

    @property
    def failures(self) -> Counter[str]:
        return self.builder.failures + self.breaker.failures

    def reset(self, observation: Any, info: dict[str, Any]) -> None:
        require(info, ("phase",), self.name, "use PandaBuildAndBreak-v0")
        self.builder.reset(observation, info)
        self.breaker.reset(observation, info)

    def act(self, observation: Any, info: dict[str, Any]) -> np.ndarray:
        if info["phase"] == "break":
            self.builder.observe(info)  # the builder must know its last place or grasp landed
            return self.breaker.act(observation, info)
        return self.builder.act(observation, info)


def block_baseline(
    agent: Callable[[BlockPerceiver], Any],
    perceiver: type[CameraBlocks | DepthBlocks] = CameraBlocks,
) -> BaselineFactory:
    """A planned baseline's factory: ``agent`` over block poses from the images (``perceiver``, noise seeded),
    or with ``oracle`` over the true poses."""

    def make(env: gym.Env, seed: int, oracle: bool) -> Any:
        return agent(OracleBlocks(env) if oracle else perceiver(noise_seed=seed))

    return make


# Each plays the benchmark's variants too (TowerBuild6, ...: ``panda_grasp_env.agents.evaluation.protocol.baseline``).
register_baseline("TowerBuild")(block_baseline(TowerBuilderAgent, DepthBlocks))
register_baseline("TowerBreak", "TowerBreakDirectional")(block_baseline(TowerBreakerAgent, DepthBlocks))
register_baseline("BuildAndBreak")(block_baseline(BuildAndBreakAgent, DepthBlocks))


# --- scripts on true poses ---------------------------------------------------------------------

#: How a script acts: it runs one primitive's parameters and says what came of it.
Act = Callable[[TopDownParameters], PrimitiveResult]


def through_env(env: gym.Env) -> Act:
    """Act through ``env.step`` of an env in the ``primitive`` action mode: the parameters written as its action
    (the heights too where the env takes them, ``primitive_z=True``; else the env reads them from the scene),
    the step's ``info`` read back as the result.  A push is the env's ``push_distance`` long: a script's push of
    another length raises ``ValueError``."""
    actions = env.unwrapped.actions
    push_distance = actions.settings.push_distance

    def act(parameters: TopDownParameters) -> PrimitiveResult:
        if isinstance(parameters, PushParameters) and parameters.distance != push_distance:
            raise ValueError(
                f"this env pushes {push_distance} m, not {parameters.distance}: make it with that push_distance"
            )
        x, y, z, yaw = parameters.x, parameters.y, parameters.z, parameters.yaw
        info = env.step(actions.encode(parameters.primitive, x, y, yaw, z))[4]
        return PrimitiveResult(
            info["primitive"],
            info["primitive_success"],
            info["primitive_reason"],
            info["primitive_sim_time"],
            object=info["primitive_object"] or None,
        )

    return act


def on_workcell(cell: Workcell) -> Act:
    """Run the primitives straight on ``cell``: the primitives alone, without an env's actions or task (the
    primitive benchmarks)."""
    return functools.partial(run, cell)


@dataclass
class TowerOutcome:
    """What a scripted tower build achieved, primitive by primitive."""

    success: bool
    base: str
    #: Primitive results in order (3 grasps + 3 places for an ideal 4-block build).
    steps: list[PrimitiveResult] = field(default_factory=list)
    #: Worst yaw misalignment of a block against the base, degrees (modulo 90).
    max_yaw_error_deg: float = float("nan")


def build_tower(cell: Workcell, act: Act) -> TowerOutcome:
    """Stack every block of ``cell`` on the one nearest the workspace centre, yaw-aligned to it, acting with
    ``act``."""
    positions = cell.block_positions()
    base = int(np.argmin(np.linalg.norm(positions[:, :2] - [0.5, 0.0], axis=1)))
    base_xy, base_yaw = positions[base, :2].copy(), float(cell.block_yaws()[base])
    outcome = TowerOutcome(success=False, base=cell.block_names[base])
    stacked = [base]
    for index in (i for i in range(len(positions)) if i != base):
        current = cell.block_positions()
        heading = clearest_grasp_heading(current, index, float(cell.block_yaws()[index]))
        result = act(GraspParameters(*current[index], heading))
        outcome.steps.append(result)
        if not result.success:
            return outcome
        top = cell.block_positions()[stacked, 2].max() + cell.config.block_size / 2
        # The place takes back the block's turn in the fingers: it lands at the base's yaw (modulo 90 degrees).
        result = act(PlaceParameters(base_xy[0], base_xy[1], top, base_yaw))
        outcome.steps.append(result)
        if not result.success:
            return outcome
        stacked.append(index)
    outcome.max_yaw_error_deg = float(np.degrees(np.abs(wrap_quarter_turn(cell.block_yaws() - base_yaw))).max())
    outcome.success = tower_is_built(cell.block_positions(), base, cell.config.block_size)
    return outcome


def push_tower(cell: Workcell, act: Act, direction: str, distance: float = 0.16) -> PrimitiveResult:
    """Push the standing tower of ``cell`` with the closed gripper at mid-height, towards ``direction`` (one of
    BREAK_DIRECTIONS), ``distance`` metres, acting with ``act``."""
    if direction not in BREAK_DIRECTIONS:
        raise ValueError(f"unknown push direction {direction!r}; valid: {list(BREAK_DIRECTIONS)}")
    centre = tower_footprint_centre(cell.block_positions())
    heading = BREAK_DIRECTIONS[direction]
    unit = np.array([np.cos(heading), np.sin(heading)])
    start = centre - unit * (cell.config.block_size / 2 + 0.04)
    height = min(cell.block_positions()[:, 2].max() / 2 + 0.01, 0.12)
    return act(PushParameters(start[0], start[1], height, heading, distance))
