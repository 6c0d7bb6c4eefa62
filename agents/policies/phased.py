"""Agents made of shipped learned policies, one per phase of a phased task: ``build_and_break_dqn`` plays
BuildAndBreak with ``tower_build_dqn`` while the task's ``info["phase"]`` is ``build`` and ``tower_break_dqn``
while it is ``break``, through the same ``env.step`` loop as every agent.

The policies act in ``pixel`` actions on heightmaps.  Each was trained on its own task's primitives (the
builder on grasp, place and push; the breaker on push alone), so an action index of the breaker is moved into
the phased task's layout: same heading, same cell, the primitive's own slot.  The heightmap's resolution and
the headings must be the same for every part (``ValueError`` otherwise); its extent may be wider than the one
they were trained on (their networks are fully convolutional: ``HeightmapQPolicy.on_grid``).

Two choices of the phased agent, made on selection seeds and not part of any training
(docs/tall-towers.md): the env it plays in may widen the heightmap (``env_options``), so that blocks a break
throws far stay in view; and a phase may hand one action to another phase's agent when its last grasp and the
place after it left the heights as they were (``unstuck_by``): a tower whose blocks all stand but one level
sits off the base's axis is not built, and the builder only lifts its top block and puts it back.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Any

import gymnasium as gym
import numpy as np

from panda_grasp_env.actions import PixelActions
from panda_grasp_env.agents.policies.learned import LearnedAgent


@dataclass(frozen=True)
class PhasedPolicies:
    """A phased agent: the benchmark tasks it plays, the shipped checkpoint that acts in each phase, and the
    acting rules a phase's checkpoint is turned on or off for it (``LearnedAgent``'s ``acting``)."""

    tasks: tuple[str, ...]
    phases: dict[str, str]  # info["phase"] -> checkpoint name
    acting: dict[str, dict[str, bool]] = field(default_factory=dict)  # info["phase"] -> rule -> on
    env_options: dict[str, Any] = field(default_factory=dict)  # over the first checkpoint's (``phased_env``)
    # info["phase"] -> the phase whose agent acts once when a grasp and its place changed no height
    unstuck_by: dict[str, str] = field(default_factory=dict)

    @property
    def first(self) -> str:
        """The checkpoint whose env options (heightmap, action mode) the task's env is made with
        (``panda_grasp_env.agents.evaluation.protocol.phased_env``)."""
        return next(iter(self.phases.values()))


#: The phased agents, by name (``evaluate.py --agents build_and_break_dqn``).  Only the four-block cycle:
#: ``tower_build_dqn`` was trained on four-block towers (``BuildAndBreak6`` would want a 6-block builder).
#: Its breaker pushes inwards (``InwardPushes``) and its heightmap reaches 30.4 cm from the workspace's middle
#: (the training envs' 22.4): a break must leave the blocks where the builder sees them.  A build stuck on a
#: tower with a level off the axis is knocked down by the breaker and built again.
WIDE_HEIGHTMAP = ((0.196, 0.804), (-0.304, 0.304), (0.0, 0.3))
PHASED_AGENTS: dict[str, PhasedPolicies] = {
    "build_and_break_dqn": PhasedPolicies(
        tasks=("BuildAndBreak",),
        phases={"build": "tower_build_dqn", "break": "tower_break_dqn"},
        acting={"break": {"inward_pushes": True}},
        env_options={"heightmap_bounds": WIDE_HEIGHTMAP},
        unstuck_by={"build": "break"},
    ),
}


def pixel_layout(env: gym.Env) -> tuple[tuple[str, ...], tuple[int, int, int, int]]:
    """The env's ``pixel`` action layout: its primitives, and (primitives, headings, rows, cols)."""
    actions = env.unwrapped.actions
    if not isinstance(actions, PixelActions):
        raise ValueError(f"a phased agent acts in pixel actions, this env's are {type(actions).__name__}")
    return tuple(actions.settings.primitives), actions.shape


class PhasedAgent:
    """Acts with the learned agent of the task's current phase (``info["phase"]``), or once with the agent of
    the phase ``unstuck_by`` names when the phase's last grasp and place changed no height.

    Entering a phase, or acting once for another, resets that phase's agent (its ``FailureMemory`` of the
    last phase described a scene that is gone)."""

    def __init__(self, name: str, env: gym.Env) -> None:
        if name not in PHASED_AGENTS:
            raise ValueError(f"unknown phased agent {name!r}; known: {sorted(PHASED_AGENTS)}")
        self.name = name
        self.primitives, self.shape = pixel_layout(env)
        self.resolution = float(env.unwrapped.actions.grid.resolution)
        self.policies = policies = PHASED_AGENTS[name]
        self.agents = {
            phase: LearnedAgent(checkpoint, acting=policies.acting.get(phase), grid=self.shape[2:])
            for phase, checkpoint in policies.phases.items()
        }
        self.slots: dict[str, tuple[tuple[int, ...], tuple[int, int, int, int]]] = {}
        for phase, agent in self.agents.items():
            args = agent.policy.network_args
            own = (len(args["primitives"]), args["rotations"], *self.shape[2:])
            if not np.isclose(args["cell_size"], self.resolution):
                raise ValueError(
                    f"{agent.name} acts on {args['cell_size']} m cells, {name}'s env's heightmap has {self.resolution}"
                )
            missing = [p for p in args["primitives"] if p not in self.primitives]
            if missing or own[1] != self.shape[1]:
                raise ValueError(
                    f"{agent.name} uses primitives {args['primitives']} at {own[1]} headings; "
                    f"{name}'s env has {self.primitives} at {self.shape[1]}"
                )
            self.slots[phase] = (tuple(self.primitives.index(p) for p in args["primitives"]), own)
        for phase, other in policies.unstuck_by.items():
            if phase not in self.agents or other not in self.agents:
                raise ValueError(f"{name}: unstuck_by {phase!r} -> {other!r} names a phase it has no agent for")
        self.phase: str | None = None
        self.block_size: float | None = None
        self.before_grasp: np.ndarray | None = None  # heights (m) when this phase's agent last chose a grasp

    def reset(self, observation: Any, info: dict[str, Any]) -> None:
        self.phase, self.before_grasp = None, None
        self.block_size = info.get("block_size")
        if self.policies.unstuck_by and self.block_size is None:
            raise ValueError(f"{self.name} compares heights in blocks, but the env's reset info has no block_size")
        for agent in self.agents.values():  # each checks now that it can see this env's observations
            agent.reset(observation, info)

    def stuck(self, observation: Any, info: dict[str, Any]) -> bool:
        """Whether the step that gave ``info`` was a successful place that, with the grasp before it, left the
        heights as they were: fewer cells changed by over 1 cm than half a block face holds (a block
        moved from the table to a tower changes two faces' worth; one put back where it was lifted, its
        edges)."""
        if self.before_grasp is None or info.get("primitive") != "place" or not info.get("primitive_success"):
            return False
        changed = np.count_nonzero(np.abs(heights_of(observation) - self.before_grasp) > 0.01)
        return changed < 0.5 * (self.block_size / self.resolution) ** 2

    def act(self, observation: Any, info: dict[str, Any]) -> int:
        phase = info.get("phase")
        if phase not in self.agents:
            raise ValueError(f"{self.name} needs info['phase'] in {sorted(self.agents)}, got {phase!r}")
        acting = phase
        if phase == self.phase and phase in self.policies.unstuck_by and self.stuck(observation, info):
            acting = self.policies.unstuck_by[phase]
            self.agents[acting].reset(observation, info)
            self.phase = None  # the phase's agent starts afresh after this action: its scene is about to go
        elif phase != self.phase:
            self.agents[phase].reset(observation, info)
            self.phase = phase
        own_primitive, rotation, row, col = np.unravel_index(
            int(self.agents[acting].act(observation, info)), self.slots[acting][1]
        )
        primitive = self.slots[acting][0][own_primitive]
        if acting == phase and self.primitives[primitive] == "grasp":
            self.before_grasp = heights_of(observation)
        elif acting != phase:
            self.before_grasp = None
        return int(np.ravel_multi_index((primitive, rotation, row, col), self.shape))


def heights_of(observation: Any) -> np.ndarray:
    """The height channel (metres above the table) of a ``heightmap`` observation (rows, cols, 4), or of a
    dict observation's ``heightmap``."""
    heightmap = observation["heightmap"] if isinstance(observation, dict) else observation
    return np.asarray(heightmap)[..., 3].copy()
