"""Agents made of shipped learned policies, one per phase of a phased task: ``build_and_break_dqn`` plays
BuildAndBreak with ``tower_build_dqn`` while the task's ``info["phase"]`` is ``build`` and ``tower_break_dqn``
while it is ``break``, through the same ``env.step`` loop as every agent.

The policies act in ``pixel`` actions on heightmaps.  Each was trained on its own task's primitives (the
builder on grasp, place and push; the breaker on push alone), so an action index of the breaker is moved into
the phased task's layout: same heading, same cell, the primitive's own slot.  The heightmap (resolution,
extent) and headings must be the same for every part; ``ValueError`` otherwise.
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

    @property
    def first(self) -> str:
        """The checkpoint whose env options (heightmap, action mode) the task's env is made with
        (``panda_grasp_env.agents.evaluation.protocol.phased_env``)."""
        return next(iter(self.phases.values()))


#: The phased agents, by name (``evaluate.py --agents build_and_break_dqn``).  Only the four-block cycle:
#: ``tower_build_dqn`` was trained on four-block towers (``BuildAndBreak6`` would want a 6-block builder).
#: Its breaker pushes inwards (``InwardPushes``): a break must leave the blocks where the builder sees them.
PHASED_AGENTS: dict[str, PhasedPolicies] = {
    "build_and_break_dqn": PhasedPolicies(
        ("BuildAndBreak",),
        {"build": "tower_build_dqn", "break": "tower_break_dqn"},
        {"break": {"inward_pushes": True}},
    ),
}


def pixel_layout(env: gym.Env) -> tuple[tuple[str, ...], tuple[int, int, int, int]]:
    """The env's ``pixel`` action layout: its primitives, and (primitives, headings, rows, cols)."""
    actions = env.unwrapped.actions
    if not isinstance(actions, PixelActions):
        raise ValueError(f"a phased agent acts in pixel actions, this env's are {type(actions).__name__}")
    return tuple(actions.settings.primitives), actions.shape


class PhasedAgent:
    """Acts with the learned agent of the task's current phase (``info["phase"]``).

    Entering a phase resets that phase's agent (its ``FailureMemory`` of the last phase described a scene
    that is gone)."""

    def __init__(self, name: str, env: gym.Env) -> None:
        if name not in PHASED_AGENTS:
            raise ValueError(f"unknown phased agent {name!r}; known: {sorted(PHASED_AGENTS)}")
        self.name = name
        self.primitives, self.shape = pixel_layout(env)
        policies = PHASED_AGENTS[name]
        self.agents = {
            phase: LearnedAgent(checkpoint, acting=policies.acting.get(phase))
            for phase, checkpoint in policies.phases.items()
        }
        self.slots: dict[str, tuple[tuple[int, ...], tuple[int, int, int, int]]] = {}
        for phase, agent in self.agents.items():
            args = agent.policy.network_args
            own = (len(args["primitives"]), args["rotations"], *self.shape[2:])
            if int(agent.policy.action_space.n) != int(np.prod(own)):
                raise ValueError(f"{agent.name} acts on another heightmap or headings than {name}'s env")
            missing = [p for p in args["primitives"] if p not in self.primitives]
            if missing or own[1] != self.shape[1]:
                raise ValueError(
                    f"{agent.name} uses primitives {args['primitives']} at {own[1]} headings; "
                    f"{name}'s env has {self.primitives} at {self.shape[1]}"
                )
            self.slots[phase] = (tuple(self.primitives.index(p) for p in args["primitives"]), own)
        self.phase: str | None = None

    def reset(self, observation: Any, info: dict[str, Any]) -> None:
        self.phase = None
        for agent in self.agents.values():  # each checks now that it can see this env's observations
            agent.reset(observation, info)

    def act(self, observation: Any, info: dict[str, Any]) -> int:
        phase = info.get("phase")
        if phase not in self.agents:
            raise ValueError(f"{self.name} needs info['phase'] in {sorted(self.agents)}, got {phase!r}")
        agent = self.agents[phase]
        if phase != self.phase:
            agent.reset(observation, info)
            self.phase = phase
        own_primitive, rotation, row, col = np.unravel_index(int(agent.act(observation, info)), self.slots[phase][1])
        primitive = self.slots[phase][0][own_primitive]
        return int(np.ravel_multi_index((primitive, rotation, row, col), self.shape))
