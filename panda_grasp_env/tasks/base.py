"""The Task protocol: what a task decides, and nothing else.

A task owns its scene (which objects, and fixtures such as a bin through
``add_fixtures``), its reset distribution, its reward, its success test, its
termination rule and its Gymnasium ids (``env_ids``).  The env owns the step
loop, the actions and the observations.  A new task is one module in
``panda_grasp_env/tasks`` with a ``Task`` subclass decorated with
``@register_task`` (``panda_grasp_env.registration``); nothing else changes.

Two kinds of step reach a task:

* *primitive* steps (``primitive`` and ``pixel`` action modes): ``evaluate`` is
  called with the :class:`~panda_grasp_env.primitives.top_down.PrimitiveResult` of the
  primitive just executed;
* *low-level* steps (``ee_delta`` and ``joint`` modes, 25 Hz): ``evaluate`` is
  called with ``None``.  Goal-conditioned tasks (``goal_conditioned = True``)
  then also publish ``achieved_goal`` / ``desired_goal`` and a vectorised
  ``compute_reward``, Fetch-style, so SB3's HER replay buffer works -- in the
  primitive modes too where ``goals_in_every_mode`` is set (the structures, whose
  goal is the whole episode's subject); elsewhere a primitive-mode agent sees the
  goal at the end of the state vector.
"""

from __future__ import annotations

from abc import ABC, abstractmethod
from collections.abc import Mapping
from dataclasses import dataclass, field, replace
from typing import Any, ClassVar

import mujoco
import numpy as np

from panda_grasp_env.geometry import is_count, is_number
from panda_grasp_env.model.scene import UNIFORM_BLOCK_COLOUR, SceneConfig
from panda_grasp_env.perception.heightmap import HeightmapGrid
from panda_grasp_env.primitives.result import PrimitiveResult
from panda_grasp_env.registration import EnvId
from panda_grasp_env.sim.workcell import Workcell

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
    #: The task's Gymnasium ids (registered by ``@register_task``).
    env_ids: ClassVar[Mapping[str, EnvId]] = {}
    #: Primitives a primitive-mode action may choose from, in action-layout order.
    primitives: ClassVar[tuple[str, ...]] = ("grasp", "push", "place")
    #: Whether the task publishes goals for the low-level action modes.
    goal_conditioned: ClassVar[bool] = False
    #: Whether a goal-conditioned task publishes them in the primitive and pixel modes too (a ``Dict``
    #: observation with the goals, rewarded by ``compute_reward``), instead of at the end of the state vector.
    goals_in_every_mode: ClassVar[bool] = False
    #: Action mode used when ``make`` is not given one.
    default_action_mode: ClassVar[str] = "primitive"
    #: Where low-level episodes may start besides the ready pose, relative to ``start_object`` (the env's
    #: ``start_<state>`` curriculum options): ``in_hand``, ``above_object``, ``behind_object``.
    start_states: ClassVar[tuple[str, ...]] = ()

    #: Length of the task's command vector (what the episode asks for, e.g. a direction), observed as the
    #: ``command`` entry; 0 for tasks without one.
    command_size: int = 0

    #: Length of ``properties()``: what the episode drew that the state vector ends with (before a goal);
    #: 0 for tasks that add nothing.
    properties_size: int = 0

    #: Set by the env: the hand's heading (radians, world) in the ``ee_delta`` action mode, which cannot turn
    #: it; None where actions choose the heading.  Tasks whose objects must fit between the fingers read it.
    fixed_hand_yaw: float | None = None

    def scene_config(self, base: SceneConfig) -> SceneConfig:
        """The scene this task needs, derived from the env's ``base`` scene (blocks, object slots)."""
        return base

    #: Keys ``env.reset(options=...)`` accepts for this task (see ``apply_reset_options``).
    reset_options: tuple[str, ...] = ()

    def apply_reset_options(self, cell: Workcell, options: dict[str, Any]) -> None:  # noqa: B027 (an optional hook)
        """Take the episode's ``reset`` options (keys among ``reset_options``; empty when none were given),
        before ``reset``.  ``ValueError`` names a bad value."""

    def add_fixtures(self, spec: mujoco.MjSpec) -> None:  # noqa: B027 (an optional hook)
        """Add the task's static fixtures (a bin, a wall, a shelf) to the scene's ``spec``: world frame,
        metres, geoms in group 0 (seen by cameras and ray casts).  Called on every model of the scene (the
        simulation's and the motion planner's), so collision checks and transit heights see them.

        Fixtures have state: ``reset`` may move them (``cell.fixtures.set_pose``) and resize their primitive
        geoms (``cell.fixtures.set_size``) for each episode, from its ``rng``; heights, ray casts, transit
        clearance and the planner's model follow.  The robot's contacts with them count (``collateral``):
        in transit, and in a work segment as a ``collision`` unless the primitive was aimed at the fixture."""

    @abstractmethod
    def reset(self, cell: Workcell, rng: np.random.Generator) -> dict[str, Any]:
        """Lay out the scene for a new episode (all randomness from ``rng``); return task info."""

    @abstractmethod
    def evaluate(self, cell: Workcell, result: PrimitiveResult | None) -> TaskStep:
        """Reward, success and termination after a step (``result`` is None for low-level steps)."""

    def on_control_step(self, cell: Workcell) -> None:  # noqa: B027 (an optional hook)
        """Called after every 25 Hz control step (inside primitives too; the env adds it as a step observer):
        track time-based conditions."""

    def start_object(self, cell: Workcell) -> int:
        """Body id of the object the ``start_states`` are relative to (tasks that have some)."""
        raise TypeError(f"task {self.name!r} has no start states")

    def command(self) -> np.ndarray:
        """The episode's command (``command_size`` float32 entries), drawn at reset."""
        return np.zeros(0, dtype=np.float32)

    def properties(self) -> np.ndarray:
        """What the episode drew that the state vector shows (``properties_size`` float32 entries)."""
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

    def dense_reward(self, achieved_goal: np.ndarray, desired_goal: np.ndarray, info: Any) -> np.ndarray:
        """The ``reward_type="dense"`` reward: ``dense_reward``'s goal distance unless a task knows better."""
        return dense_reward(achieved_goal, desired_goal, info)

    def goal_heightmap(self, grid: HeightmapGrid) -> np.ndarray | None:
        """The goal as a heightmap on ``grid`` ((rows, cols) float32 metres above its floor) for pixel agents,
        or None where the goal has no shape to draw (the default)."""
        return None


#: The ``reward_type`` options of goal-conditioned low-level envs.
REWARD_TYPES = ("sparse", "dense")


def dense_reward(achieved_goal: np.ndarray, desired_goal: np.ndarray, info: Any = None) -> np.ndarray:
    """Dense goal reward (``reward_type="dense"``, panda-gym's): minus the distance, metres, between the
    achieved and the desired goal vectors (all their points together).  Vectorised like ``compute_reward``."""
    achieved = np.asarray(achieved_goal, dtype=float)
    desired = np.asarray(desired_goal, dtype=float)
    return -np.linalg.norm(achieved - desired, axis=-1).astype(np.float32)


def goals_reached(achieved_goal: np.ndarray, desired_goal: np.ndarray) -> np.ndarray:
    """Whether every 3-D point of the goal is within ``GOAL_THRESHOLD``; goals are (..., 3k) arrays."""
    achieved = np.asarray(achieved_goal, dtype=float)
    desired = np.asarray(desired_goal, dtype=float)
    distances = np.linalg.norm((achieved - desired).reshape(*achieved.shape[:-1], -1, 3), axis=-1)
    return np.all(distances < GOAL_THRESHOLD, axis=-1)


def with_scene(base: SceneConfig, **changes: Any) -> SceneConfig:
    """``base`` with some fields replaced (validated by SceneConfig)."""
    return replace(base, **changes)


#: The block tasks' ``block_colours`` option: ``"distinct"``, each block its scene colour (red, green, blue,
#: yellow, ... by default: ``DEFAULT_COLOURS``), or ``"uniform"``, every block ``UNIFORM_BLOCK_COLOUR``, so that only shape and place tell
#: them apart (perception that does not read colour).  Block names stay the colours' (``block_red``, ...):
#: they name the blocks, however they look.
BLOCK_COLOURINGS = ("distinct", "uniform")


def check_block_colours(block_colours: Any) -> None:
    """``ValueError`` naming the ``block_colours`` task option unless it is one of ``BLOCK_COLOURINGS``."""
    valid = isinstance(block_colours, str) and block_colours in BLOCK_COLOURINGS
    check_option("block_colours", block_colours, valid, f"one of {list(BLOCK_COLOURINGS)}")


#: Blocks the tower tasks (TowerBuild, TowerBreak, BuildAndBreak) take, fewest and most: a base and one block on
#: it, up to a 40 cm tower of eight (one per default colour, ``DEFAULT_COLOURS``).
TOWER_BLOCKS = (2, 8)


def check_tower_blocks(n_blocks: Any) -> None:
    """``ValueError`` naming the ``n_blocks`` task option unless it is an int within ``TOWER_BLOCKS``."""
    low, high = TOWER_BLOCKS
    check_option("n_blocks", n_blocks, is_count(n_blocks) and low <= n_blocks <= high, f"an int in [{low}, {high}]")


def block_scene(base: SceneConfig, n_blocks: int, block_colours: str) -> SceneConfig:
    """``base`` with ``n_blocks`` blocks, coloured as the ``block_colours`` option says, and no other objects."""
    colours = dict.fromkeys(base.colours, UNIFORM_BLOCK_COLOUR) if block_colours == "uniform" else base.colours
    return with_scene(base, n_blocks=n_blocks, n_objects=0, colours=colours)


def is_interval(value: Any) -> bool:
    """Whether ``value`` is a ``(low, high)`` pair of numbers with low <= high."""
    pair = tuple(value) if isinstance(value, (tuple, list)) else ()
    return len(pair) == 2 and all(map(is_number, pair)) and pair[0] <= pair[1]


def check_option(name: str, value: Any, valid: bool, expected: str) -> None:
    """Raise ``ValueError`` naming a task option whose value is invalid."""
    if not valid:
        raise ValueError(f"task option {name!r} must be {expected}, got {value!r}")
