"""The Task protocol: what a task decides, and nothing else.

A task owns its reset distribution (which objects, where), its reward, its
success test and its termination rule.  The env owns the step loop, the
actions and the observations.  A new task is one small module with a
``Task`` subclass decorated with ``@register_task``; the env never changes.

Two kinds of step reach a task:

* *primitive* steps (``primitive`` and ``pixel`` action modes): ``evaluate`` is
  called with the :class:`~panda_grasp_env.primitives.PrimitiveResult` of the
  primitive just executed;
* *low-level* steps (``ee_delta`` and ``joint`` modes, 25 Hz): ``evaluate`` is
  called with ``None``.  Goal-conditioned tasks (``goal_conditioned = True``)
  then also publish ``achieved_goal`` / ``desired_goal`` and a vectorised
  ``compute_reward``, Fetch-style, so SB3's HER replay buffer works.
"""

from __future__ import annotations

import inspect
from abc import ABC, abstractmethod
from dataclasses import dataclass, field, replace
from typing import Any, ClassVar

import numpy as np

from panda_grasp_env.geometry import is_number
from panda_grasp_env.primitives import PrimitiveResult
from panda_grasp_env.scene import SceneConfig
from panda_grasp_env.workcell import Workcell

#: Distance (metres) under which an achieved goal counts as reached (Fetch and panda-gym use 5 cm).
GOAL_THRESHOLD = 0.05


@dataclass
class TaskStep:
    """A task's verdict on one env step: ``terminated`` where the MDP ends (the task done or lost for good),
    ``truncated`` where the task stops it for a reason the observation does not show (a count of attempts)."""

    reward: float
    success: bool
    terminated: bool
    info: dict[str, Any] = field(default_factory=dict)
    truncated: bool = False


class Task(ABC):
    """Base class of all tasks.  Subclasses take their options as keyword arguments and implement
    ``reset`` and ``evaluate``; goal-conditioned ones also ``achieved_goal`` and ``desired_goal``."""

    #: Registry name (``task=`` of the env).
    name: ClassVar[str] = ""
    #: Primitives a primitive-mode action may choose from, in action-layout order.
    primitives: ClassVar[tuple[str, ...]] = ("grasp", "push", "place")
    #: Whether the task publishes goals for the low-level action modes.
    goal_conditioned: ClassVar[bool] = False
    #: Action mode used when ``make`` is not given one.
    default_action_mode: ClassVar[str] = "primitive"
    #: Where low-level episodes may start besides the ready pose, relative to ``start_object`` (the env's
    #: ``start_<state>`` curriculum options): ``in_hand``, ``above_object``, ``behind_object``.
    start_states: ClassVar[tuple[str, ...]] = ()

    #: Length of the task's command vector (what the episode asks for, e.g. a direction), observed as the
    #: ``command`` entry; 0 for tasks without one.
    command_size: int = 0

    #: Set by the env: the hand's heading (radians, world) in the ``ee_delta`` action mode, which cannot turn
    #: it; None where actions choose the heading.  Tasks whose objects must fit between the fingers read it.
    fixed_hand_yaw: float | None = None

    def scene_config(self, base: SceneConfig) -> SceneConfig:
        """The scene this task needs, derived from the env's ``base`` scene (blocks, object slots)."""
        return base

    @abstractmethod
    def reset(self, cell: Workcell, rng: np.random.Generator) -> dict[str, Any]:
        """Lay out the scene for a new episode (all randomness from ``rng``); return task info."""

    @abstractmethod
    def evaluate(self, cell: Workcell, result: PrimitiveResult | None) -> TaskStep:
        """Reward, success and termination after a step (``result`` is None for low-level steps)."""

    def on_control_step(self, cell: Workcell) -> None:  # noqa: B027 (an optional hook)
        """Called after every 25 Hz control step (inside primitives too): track time-based conditions."""

    def start_object(self, cell: Workcell) -> int:
        """Body id of the object the ``start_states`` are relative to (tasks that have some)."""
        raise TypeError(f"task {self.name!r} has no start states")

    def command(self) -> np.ndarray:
        """The episode's command (``command_size`` float32 entries), drawn at reset."""
        return np.zeros(0, dtype=np.float32)

    @property
    def ideal_actions(self) -> int | None:
        """Fewest primitive actions that can solve an episode (for action efficiency), if known."""
        return None

    # --- goal-conditioned interface (``goal_conditioned = True``) ------------
    @property
    def goal_size(self) -> int:
        """Length of the goal vectors (3 per goal point)."""
        return 3

    def achieved_goal(self, cell: Workcell) -> np.ndarray:
        """Where the goal's points are now (goal-conditioned tasks override this)."""
        raise TypeError(f"task {self.name!r} is not goal-conditioned: it has no achieved goal")

    def desired_goal(self) -> np.ndarray:
        """Where the goal's points should be (goal-conditioned tasks override this)."""
        raise TypeError(f"task {self.name!r} is not goal-conditioned: it has no desired goal")

    def compute_reward(self, achieved_goal: np.ndarray, desired_goal: np.ndarray, info: Any) -> np.ndarray:
        """Sparse reward: 0 where every goal component is within ``GOAL_THRESHOLD``, else -1.

        Vectorised: goals may carry leading batch dimensions (SB3's HER relabels in batches).
        """
        return goals_reached(achieved_goal, desired_goal).astype(np.float32) - 1.0


def goals_reached(achieved_goal: np.ndarray, desired_goal: np.ndarray) -> np.ndarray:
    """Whether every 3-D point of the goal is within ``GOAL_THRESHOLD``; goals are (..., 3k) arrays."""
    achieved = np.asarray(achieved_goal, dtype=float)
    desired = np.asarray(desired_goal, dtype=float)
    distances = np.linalg.norm((achieved - desired).reshape(*achieved.shape[:-1], -1, 3), axis=-1)
    return np.all(distances < GOAL_THRESHOLD, axis=-1)


TASKS: dict[str, type[Task]] = {}


def register_task(cls: type[Task]) -> type[Task]:
    """Class decorator: make a task available to the env as ``task=cls.name``."""
    if not cls.name or cls.name in TASKS:
        raise ValueError(f"task name {cls.name!r} is empty or already registered")
    TASKS[cls.name] = cls
    return cls


def make_task(name: str, options: dict[str, Any]) -> Task:
    """Instantiate task ``name``; unknown names or options raise ``ValueError`` listing the valid ones."""
    if not isinstance(name, str) or name not in TASKS:
        raise ValueError(f"unknown task {name!r}; valid: {sorted(TASKS)}")
    cls = TASKS[name]
    valid = [p for p in inspect.signature(cls.__init__).parameters if p != "self"]
    unknown = sorted(set(options) - set(valid))
    if unknown:
        raise ValueError(f"unknown option(s) {unknown} for task {name!r}; valid: {valid}")
    return cls(**options)


def with_scene(base: SceneConfig, **changes: Any) -> SceneConfig:
    """``base`` with some fields replaced (validated by SceneConfig)."""
    return replace(base, **changes)


def is_interval(value: Any) -> bool:
    """Whether ``value`` is a ``(low, high)`` pair of numbers with low <= high."""
    pair = tuple(value) if isinstance(value, (tuple, list)) else ()
    return len(pair) == 2 and all(map(is_number, pair)) and pair[0] <= pair[1]


def check_option(name: str, value: Any, valid: bool, expected: str) -> None:
    """Raise ``ValueError`` naming a task option whose value is invalid."""
    if not valid:
        raise ValueError(f"task option {name!r} must be {expected}, got {value!r}")
