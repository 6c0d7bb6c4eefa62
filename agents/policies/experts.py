"""Scripted low-level experts: state machines that act through the ``ee_delta`` action space at 25 Hz.

They read only what a learned policy reads -- the goal-conditioned observation (the state vector, the
achieved and desired goals) and the reset ``info`` (the block size) -- and steer the grasp site towards
waypoints: no simulator state, no planner.  ``LiftExpert`` (PandaGrasp-v0 in ``ee_delta``),
``PushExpert`` (PandaPush-v0) and ``StackExpert`` (PandaStack-v0): demonstrators for imitation and
RL-from-demonstrations, and the low-level tasks' reference figures in ``evaluate.py`` (agent ``expert``).
World frame, metres.
"""

from __future__ import annotations

from abc import ABC, abstractmethod
from typing import Any

import numpy as np

from panda_grasp_env.actions import EE_STEP, LOW_LEVEL_BOUNDS, EEDeltaActions
from panda_grasp_env.agents.policies.base import require
from panda_grasp_env.agents.policies.registry import register_expert

#: Gripper commands of the ee_delta mode.
OPEN, CLOSED = -1.0, 1.0
#: The ee_delta mode keeps its integrated target at most this far ahead of the hand horizontally (metres).
MAX_LAG = EEDeltaActions.MAX_LAG
#: Control steps the fingers are given to close on an object, and to open off it.
CLOSE_STEPS, OPEN_STEPS = 8, 6
#: Height (metres) of the grasp site above an object's centre while the open hand moves over it.
HOVER = 0.08
#: The hand counts as settled below this speed, m/s.
SETTLED = 0.03


class LowLevelExpert(ABC):
    """Phases of waypoints for the grasp site; subclasses choose the waypoint and gripper of each phase."""

    name = "expert"
    first_phase = "above"

    def reset(self, observation: Any, info: dict[str, Any]) -> None:
        if not isinstance(observation, dict) or not {"observation", "achieved_goal", "desired_goal"} <= set(
            observation
        ):
            raise ValueError(
                f"{self.name} reads the goal-conditioned Dict observation of an ee_delta env with obs_mode='state'"
            )
        require(info, ("block_size",), self.name, "use an env from panda_grasp_env")
        self.block_size = float(info["block_size"])
        self.phase, self.steps_in_phase = self.first_phase, 0
        #: The mode's integrated grasp-site target, followed as the mode documents it (it starts at the hand).
        self.target = observation["observation"][:3].astype(float)

    def next_phase(self, phase: str) -> None:
        self.phase, self.steps_in_phase = phase, 0

    def steer(self, hand: np.ndarray, waypoint: np.ndarray, gripper: float, speed: float = 1.0) -> np.ndarray:
        """The action that puts the mode's target on ``waypoint`` (clipped to the bounds) as far as one step
        allows; the servo then brings the hand there.  Commanding from the hand instead overshoots: the target
        runs ahead of a lagging hand.  ``speed``: the share of the mode's largest step allowed (0-1]."""
        lag = self.target[:2] - hand[:2]
        if np.linalg.norm(lag) > MAX_LAG:
            self.target[:2] = hand[:2] + lag * (MAX_LAG / np.linalg.norm(lag))
        waypoint = np.clip(waypoint, LOW_LEVEL_BOUNDS[:, 0], LOW_LEVEL_BOUNDS[:, 1])
        move = np.clip((waypoint - self.target) / EE_STEP, -speed, speed)
        self.target = np.clip(self.target + move * EE_STEP, LOW_LEVEL_BOUNDS[:, 0], LOW_LEVEL_BOUNDS[:, 1])
        return np.array([*move, gripper], dtype=np.float32)

    def act(self, observation: dict[str, np.ndarray], info: dict[str, Any]) -> np.ndarray:
        self.steps_in_phase += 1
        hand = observation["observation"][:3].astype(float)
        self.hand_speed = float(np.linalg.norm(observation["observation"][6:9]))
        return self.waypoint_action(
            hand, observation["achieved_goal"].astype(float), observation["desired_goal"].astype(float)
        )

    @abstractmethod
    def waypoint_action(self, hand: np.ndarray, obj: np.ndarray, goal: np.ndarray) -> np.ndarray:
        """The action of this step, from the grasp site's, the object's and the goal's positions (world, m)."""


def reached(hand: np.ndarray, waypoint: np.ndarray, tolerance: float) -> bool:
    """Whether the grasp site is within ``tolerance`` metres of ``waypoint`` (clipped to the bounds); (x, y)
    or (x, y, z)."""
    bounds = LOW_LEVEL_BOUNDS[: len(waypoint)]
    waypoint = np.clip(waypoint, bounds[:, 0], bounds[:, 1])
    return bool(np.linalg.norm(hand - waypoint) < tolerance)


class PickAndPlaceExpert(LowLevelExpert):
    """Over the object, down to its centre, close, carry its centre to a point, and (``release``) put it down."""

    release = False

    def waypoint_action(self, hand: np.ndarray, obj: np.ndarray, goal: np.ndarray) -> np.ndarray:
        above_object = obj + [0.0, 0.0, HOVER]
        if self.phase == "above":
            if reached(hand[:2], above_object[:2], 0.006) and hand[2] > obj[2] + 0.03:
                self.next_phase("down")
            return self.steer(hand, above_object if hand[2] > obj[2] + 0.03 else hand + [0, 0, HOVER], OPEN)
        if self.phase == "down":
            # Slowly, and only closing once the hand has settled on the centre: fingers closing off-centre
            # squeeze a round object out sideways.
            if (reached(hand, obj, 0.004) and self.hand_speed < SETTLED) or self.steps_in_phase > 40:
                self.grasp_point = obj.copy()
                self.next_phase("close")
            return self.steer(hand, obj, OPEN, speed=0.5)
        if self.phase == "close":
            if self.steps_in_phase >= CLOSE_STEPS:
                self.next_phase("carry")
            return self.steer(hand, self.grasp_point, CLOSED)
        if not self.release:  # lift: hold the object at the goal
            return self.steer(hand, goal, CLOSED)
        # Aim the held object's centre, not the hand, at the goal: a block held off-centre and set down by
        # the hand's position overhangs the base and slides off as the fingers open.
        goal = goal + (hand - obj if self.phase in ("carry", "lower") else self.release_offset)
        above_goal = goal + [0.0, 0.0, 0.04]
        if self.phase == "carry":
            if reached(hand, above_goal, 0.01):
                self.next_phase("lower")
            # Rise first, then across: the held object clears what stands around the goal.
            target = above_goal if hand[2] > goal[2] + 0.02 else np.array([*hand[:2], above_goal[2]])
            return self.steer(hand, target, CLOSED)
        if self.phase == "lower":
            if reached(hand, goal, 0.006) or self.steps_in_phase > 30:
                self.release_offset = hand - obj
                self.next_phase("open")
            return self.steer(hand, goal, CLOSED)
        if self.phase == "open":
            if self.steps_in_phase >= OPEN_STEPS:
                self.next_phase("retreat")
            return self.steer(hand, goal, OPEN)
        return self.steer(hand, goal + [0.0, 0.0, HOVER], OPEN)


@register_expert("Lift")
class LiftExpert(PickAndPlaceExpert):
    """Lift: grasp the object at its centre and hold it at the goal above the table."""

    name = "lift_expert"


@register_expert("Stack")
class StackExpert(PickAndPlaceExpert):
    """PandaStack-v0: grasp the loose block, carry it over the base and set it down where the goal is."""

    name = "stack_expert"
    release = True


@register_expert("Push")
class PushExpert(LowLevelExpert):
    """Push: the closed hand comes down behind the block on the line from the goal through it, then pushes
    along that line, re-aimed every step: the waypoint is the contact point behind the block, moved forward
    and back onto the line; if the hand loses the block it comes round again from above.  A block that tips
    onto its leading edge and digs in (its centre sinks) is pushed higher from then on."""

    name = "push_expert"
    #: Stop pushing this close to the goal (metres; success is within 5 cm): the block slides on a little.
    STOP = 0.03
    #: Grasp-site height above the block's centre while going round it, metres: the fingertips clear its top
    #: even when the hand dips during a fast move.
    CLEAR = HOVER
    #: Grasp-site height above the block's resting centre while pushing, metres.  Lower, the fingertips'
    #: rounded ends lever the block up by its bottom edge; higher, it tips forward.
    PUSH_HEIGHT = 0.005
    #: How far ahead of the contact point the pushing waypoint runs, metres.
    LEAD = 0.03
    #: A block whose centre sinks this far below where it rested at the reset has tipped onto its leading
    #: edge and dug into the table (metres) ...
    DUG_IN = 0.002
    #: ... and the hand pushes this much higher for the rest of the episode (metres): the push then slides
    #: it instead of pressing the edge further in.
    DUG_IN_RAISE = 0.006

    def reset(self, observation: Any, info: dict[str, Any]) -> None:
        super().reset(observation, info)
        self.resting_height = float(observation["achieved_goal"][2])
        self.raised = 0.0

    def waypoint_action(self, hand: np.ndarray, obj: np.ndarray, goal: np.ndarray) -> np.ndarray:
        offset = goal[:2] - obj[:2]
        distance = float(np.linalg.norm(offset))
        contact = self.block_size / 2 + 0.012  # hand centre to block centre when touching
        if self.phase == "push" and obj[2] < self.resting_height - self.DUG_IN:
            self.raised = self.DUG_IN_RAISE
        # From the block's resting centre, not its current one: a tipping block must not lift the hand.
        height = self.block_size / 2 + self.PUSH_HEIGHT + self.raised
        if self.phase in ("above", "down"):
            self.direction = offset / max(distance, 1e-6)  # the line is fixed once the push starts
        direction = self.direction
        behind = np.array([*(obj[:2] - direction * (contact + 0.015)), height])
        if self.phase == "above":
            above = behind + [0.0, 0.0, self.CLEAR]
            if reached(hand[:2], above[:2], 0.01):
                self.next_phase("down")
            return self.steer(hand, above, CLOSED)
        if self.phase == "down":
            if abs(hand[2] - height) < 0.01 or self.steps_in_phase > 15:
                self.next_phase("push")
            return self.steer(hand, behind, CLOSED)
        side = np.array([-direction[1], direction[0]])
        off_line = abs(float(side @ (goal[:2] - obj[:2])))  # the goal is no longer ahead of the block
        lost = abs(float(side @ (hand[:2] - obj[:2]))) > self.block_size / 2 or direction @ (obj[:2] - hand[:2]) < 0
        if lost or (off_line > 0.025 and distance > self.STOP):
            self.next_phase("above")
            return self.steer(hand, hand + [0.0, 0.0, self.CLEAR], CLOSED)
        if distance < self.STOP:
            return self.steer(hand, hand, CLOSED)
        along = float(direction @ offset)  # how far the block still has to go along the line
        waypoint = obj[:2] - direction * contact + direction * min(max(along - self.STOP, 0.0), self.LEAD)
        return self.steer(hand, np.array([*waypoint, height]), CLOSED)
