"""Action modes: how an env action becomes motion.

* ``primitive`` -- ``Box``: one motion primitive per step, chosen by the
  largest of its per-primitive scores, placed at normalised (x, y[, z]) with
  heading ``yaw``;
* ``pixel`` -- ``Discrete``: VPG's layout, primitive x rotation x heightmap
  cell, with ``action_masks()`` for MaskablePPO;
* ``pixel_factored`` -- ``MultiDiscrete``: the same as (primitive, rotation,
  row, column), with per-dimension masks, for off-the-shelf clients;
* ``ee_delta`` -- ``Box(4)``: end-effector displacement and gripper at 25 Hz
  (Fetch / panda-gym style);
* ``joint`` -- ``Box(8)``: arm joint-position deltas and gripper at 25 Hz;
* ``grasp_pose`` -- ``Box(7)``: one 6-DOF grasp through the motion stack.

Each mode is a class in ``ACTION_MODES`` that builds itself from an ``ActionContext``
and describes its own layout (``layout()``, ``info["action_layout"]``).

Every mode validates its input the same way: wrong shape or dtype, NaN or inf
raise ``ValueError`` naming the problem; out-of-range continuous values are
clipped and counted.
"""

from __future__ import annotations

import math
from abc import ABC, abstractmethod
from collections.abc import Callable
from dataclasses import dataclass
from typing import TYPE_CHECKING, Any, ClassVar

import cv2
import gymnasium as gym
import mujoco
import numpy as np

from panda_grasp_env.control.controller import JacobianServo, JointTargets
from panda_grasp_env.geometry import is_count
from panda_grasp_env.model.robot import FINGER_OPEN, HOME_YAW
from panda_grasp_env.perception.heightmap import HeightmapGrid
from panda_grasp_env.primitives.parameters import (
    MIN_GRASP_HEIGHT,
    PoseGraspParameters,
    PrimitiveSettings,
    to_normalised,
    to_world,
)
from panda_grasp_env.primitives.registry import PRIMITIVES, Aim, Target, run
from panda_grasp_env.primitives.result import PrimitiveResult
from panda_grasp_env.sim.motion import WORKSPACE
from panda_grasp_env.sim.workcell import Workcell

if TYPE_CHECKING:
    from panda_grasp_env.primitives.pose_grasp import MotionStack

#: Largest end-effector displacement per ee_delta step (metres; 25 Hz -> 0.75 m/s).
EE_STEP = 0.03
#: Largest joint change per joint step, radians.
JOINT_STEP = 0.05
#: Grasp-site box the ee_delta mode keeps its targets in (fingertips stay clear of the table).
LOW_LEVEL_BOUNDS = np.array([WORKSPACE[0], WORKSPACE[1], [MIN_GRASP_HEIGHT, WORKSPACE[2, 1]]])


def validate_box_action(action: Any, space: gym.spaces.Box) -> tuple[np.ndarray, int]:
    """Checked float64 copy of a continuous action, clipped to the space, and how many components were clipped."""
    array = np.asarray(action)
    if array.dtype.kind not in "fiu":
        raise ValueError(f"action must be a numeric array, got dtype {array.dtype}")
    if array.shape != space.shape:
        raise ValueError(f"action has shape {array.shape}, expected {space.shape}")
    array = array.astype(np.float64)
    if not math.isfinite(array.sum()) and not np.isfinite(array).all():  # the sum alone: the common case, fast
        bad = ~np.isfinite(array)
        raise ValueError(f"action contains NaN or inf at index {np.flatnonzero(bad).tolist()}: {array.tolist()}")
    clipped = np.minimum(np.maximum(array, space.low), space.high)
    return clipped, int(np.count_nonzero(clipped != array))


def encode_primitive(
    primitives: tuple[str, ...] | list[str],
    with_z: bool,
    name: str,
    x: float,
    y: float,
    yaw: float,
    z: float | None = None,
) -> np.ndarray:
    """A ``primitive``-mode action running ``name`` at world (x, y[, z]) metres with heading ``yaw`` radians.

    ``primitives`` and ``with_z`` describe the env's layout; ``reset`` publishes them in
    ``info["action_layout"]``, so agents can build actions without touching the env.
    """
    if name not in primitives:
        raise ValueError(f"primitive {name!r} not available here; valid: {list(primitives)}")
    scores = [1.0 if p == name else -1.0 for p in primitives] if len(primitives) > 1 else []
    if with_z and z is None:
        raise ValueError("this env's primitive actions include z: pass z")
    position = to_normalised([x, y, z] if with_z else [x, y])
    wrapped_yaw = (yaw + np.pi) % (2 * np.pi) - np.pi
    return np.array([*scores, *position, wrapped_yaw / np.pi], dtype=np.float32)


@dataclass(frozen=True)
class ActionContext:
    """Everything an action mode may build itself from; each mode takes what it needs."""

    cell: Workcell
    settings: PrimitiveSettings
    grid: HeightmapGrid
    #: Headings of the pixel modes.
    rotations: int
    #: The current heightmap (metres above the table on ``grid``), for the pixel modes' masks.
    heightmap: Callable[[], np.ndarray]
    block_gripper: bool = False
    #: OMPL planner of the ``grasp_pose`` mode.
    planner: str = "RRTConnect"


class ActionMode(ABC):
    """One way of acting.  ``low_level`` modes run one 25 Hz control step per env step, through the workcell's
    ``physics.control_step`` with their controller; ``fixed_hand_yaw`` modes keep the hand at ``HOME_YAW``
    (tasks then need not turn it)."""

    name: ClassVar[str]
    low_level: ClassVar[bool]
    fixed_hand_yaw: ClassVar[bool] = False
    space: gym.Space

    @classmethod
    @abstractmethod
    def build(cls, context: ActionContext) -> ActionMode:
        """The mode, for the env described by ``context``."""

    def validate(self, action: Any) -> tuple[Any, int]:
        """Checked action and the number of clipped components."""
        return validate_box_action(action, self.space)

    def reset(self, cell: Workcell, rng: np.random.Generator) -> None:  # noqa: B027 (an optional hook)
        """Called at every env reset, after the task laid out the scene; ``rng`` is the env's own generator."""

    def layout(self) -> dict[str, Any] | None:
        """What an agent needs to write this mode's actions (``info["action_layout"]``), or None if the space
        says it all."""
        return None

    @abstractmethod
    def execute(self, cell: Workcell, action: Any) -> PrimitiveResult | None:
        """Carry out a validated action: one primitive (its result) or one control step (None)."""


class PrimitiveActions(ActionMode):
    """``Box`` in [-1, 1]: [score per primitive (if more than one)] + [x, y, (z,) yaw].

    x, y span ``WORKSPACE`` (metres, world frame), z spans 0-0.3 m and yaw
    spans [-pi, pi] (closing-axis heading for grasp/place, travel heading for
    push/impulse).  The primitive with the highest score runs.
    """

    name = "primitive"
    low_level = False

    @classmethod
    def build(cls, context: ActionContext) -> PrimitiveActions:
        return cls(context.settings)

    def __init__(self, settings: PrimitiveSettings) -> None:
        self.settings = settings
        self.n_scores = len(settings.primitives) if len(settings.primitives) > 1 else 0
        size = self.n_scores + (4 if settings.with_z else 3)
        self.space = gym.spaces.Box(-1.0, 1.0, (size,), dtype=np.float32)

    def layout(self) -> dict[str, Any]:
        settings = self.settings
        return {
            "mode": self.name,
            "primitives": list(settings.primitives),
            "primitive_z": settings.with_z,
            "push_distance": settings.push_distance,
        }

    def decode(self, action: np.ndarray) -> Aim:
        """Where a validated action points its primitive, in world units (z None: the scene's height)."""
        primitives = self.settings.primitives
        name = primitives[int(np.argmax(action[: self.n_scores]))] if self.n_scores else primitives[0]
        rest = action[self.n_scores :]
        position = to_world(rest[:-1])  # x, y[, z]
        z = position[2] if self.settings.with_z else None
        return Aim(name, position[0], position[1], float(rest[-1]) * np.pi, z)

    def encode(self, name: str, x: float, y: float, yaw: float, z: float | None = None) -> np.ndarray:
        """The action that runs primitive ``name`` at world (x, y[, z]) metres with heading ``yaw`` radians."""
        return encode_primitive(self.settings.primitives, self.settings.with_z, name, x, y, yaw, z)

    def execute(self, cell: Workcell, action: np.ndarray) -> PrimitiveResult:
        return run(cell, self.decode(action).parameters(cell, self.settings))


class PixelActions(ActionMode):
    """``Discrete(P * R * H * W)``: index = ((primitive * R + rotation) * H + row) * W + column (VPG's layout).

    The cell's centre on the heightmap grid gives (x, y); rotation r gives the
    heading 2 pi r / R; heights are automatic.  ``action_masks`` allows grasps
    and pushes only on or near objects (heightmap > 1 cm, dilated by ``NEAR``)
    with an empty hand, and places only with something in the hand.
    """

    name = "pixel"
    low_level = False
    OCCUPIED = 0.01  # metres: a heightmap cell above this holds an object
    NEAR = 0.05  # metres: pushes may start this far from an object (the closed hand is ~6 cm thick along a push)

    def __init__(
        self, settings: PrimitiveSettings, grid: HeightmapGrid, rotations: int, heightmap: Callable[[], np.ndarray]
    ) -> None:
        if not is_count(rotations) or rotations < 1:
            raise ValueError(f"rotations must be a positive int, got {rotations!r}")
        self.settings, self.grid, self.rotations = settings, grid, rotations
        self.heightmap = heightmap
        self.shape = (len(settings.primitives), rotations, *grid.shape)
        self.space = gym.spaces.Discrete(int(np.prod(self.shape)))

    @classmethod
    def build(cls, context: ActionContext) -> PixelActions:
        return cls(context.settings, context.grid, context.rotations, context.heightmap)

    def layout(self) -> dict[str, Any]:
        return {
            "mode": self.name,
            "primitives": list(self.settings.primitives),
            "shape": list(self.shape),  # (primitive, rotation, row, column): the index's layout
            **self.grid.layout(),
            "push_distance": self.settings.push_distance,
        }

    def validate(self, action: Any) -> tuple[int, int]:
        array = np.asarray(action)
        if array.shape != () or array.dtype.kind not in "iu":  # Discrete: one index, as its sample() gives
            raise ValueError(f"pixel action must be one integer index, got {action!r} (dtype {array.dtype})")
        index = int(array.reshape(()))
        if not 0 <= index < self.space.n:
            raise ValueError(f"pixel action {index} outside [0, {self.space.n})")
        return index, 0

    def decode(self, index: int) -> Aim:
        """Where an action index points its primitive: the cell's centre and the rotation's heading."""
        p, r, row, col = np.unravel_index(index, self.shape)
        x, y = self.grid.cell_centres(row, col)
        return Aim(self.settings.primitives[p], float(x), float(y), 2 * np.pi * r / self.rotations)

    def execute(self, cell: Workcell, action: int) -> PrimitiveResult:
        return run(cell, self.decode(action).parameters(cell, self.settings))

    def action_masks(self, holding: bool) -> np.ndarray:
        """Boolean mask over the flat action space (True = allowed)."""
        occupied = (self.heightmap() > self.OCCUPIED).astype(np.uint8)
        radius = max(1, int(round(self.NEAR / self.grid.resolution)))
        near = cv2.dilate(occupied, cv2.getStructuringElement(cv2.MORPH_ELLIPSE, (2 * radius + 1,) * 2)).astype(bool)
        where = {Target.ANYWHERE: True, Target.OBJECT: occupied.astype(bool), Target.NEAR_OBJECT: near}
        masks = np.zeros(self.shape, dtype=bool)
        for p, name in enumerate(self.settings.primitives):
            primitive = PRIMITIVES[name]  # a load in the hand to place, else an empty hand
            masks[p] = where[primitive.target] & (holding == primitive.needs_load)
        if not masks.any():
            masks[:] = True  # nothing sensible to do: let the agent act anyway
        return masks.ravel()


class FactoredPixelActions(PixelActions):
    """``MultiDiscrete([P, R, H, W])``: the ``pixel`` action as (primitive, rotation, row, column).

    For off-the-shelf clients that handle neither a 10^5-10^6-way ``Discrete`` nor VPG's dense Q-maps
    (SB3's PPO and A2C, MaskablePPO): the same cells and headings, one small categorical per dimension.
    ``action_masks`` is per dimension, concatenated (MaskablePPO's ``MultiDiscrete`` layout): a value is
    allowed where some allowed ``pixel`` action has it, so a combination of allowed values may still be one
    the joint mask forbids (a grasp on an empty cell): it runs, and fails as it would in ``pixel`` mode.
    """

    name = "pixel_factored"

    def __init__(
        self, settings: PrimitiveSettings, grid: HeightmapGrid, rotations: int, heightmap: Callable[[], np.ndarray]
    ) -> None:
        super().__init__(settings, grid, rotations, heightmap)
        self.space = gym.spaces.MultiDiscrete(self.shape)

    def validate(self, action: Any) -> tuple[int, int]:
        array = np.asarray(action)
        if array.shape != (4,) or array.dtype.kind not in "iu":
            raise ValueError(
                f"pixel_factored action must be 4 integers (primitive, rotation, row, column), "
                f"got {action!r} (dtype {array.dtype})"
            )
        if np.any(array < 0) or np.any(array >= self.space.nvec):
            raise ValueError(f"pixel_factored action {array.tolist()} outside [0, {self.space.nvec.tolist()})")
        return int(np.ravel_multi_index(tuple(int(v) for v in array), self.shape)), 0

    def action_masks(self, holding: bool) -> np.ndarray:
        """Boolean masks of each dimension, concatenated (``sum(shape)`` entries; True = allowed)."""
        joint = super().action_masks(holding).reshape(self.shape)
        axes = range(joint.ndim)
        return np.concatenate([joint.any(axis=tuple(a for a in axes if a != axis)) for axis in axes])


class EEDeltaActions(ActionMode):
    """``Box(4)`` in [-1, 1]: grasp-site displacement (dx, dy, dz) x ``EE_STEP`` metres, and gripper.

    The hand keeps pointing down with a fixed heading.  Gripper: -1 fully
    open, +1 closed (position target between; squeeze force limited).  With
    ``block_gripper`` (panda-gym's Push) the action is ``Box(3)`` and the
    fingers stay closed, so a pushed block cannot slip between them.
    """

    name = "ee_delta"
    low_level = True
    fixed_hand_yaw = True
    MAX_LAG = 0.02  # metres, horizontal
    LOW, HIGH = LOW_LEVEL_BOUNDS[:, 0].copy(), LOW_LEVEL_BOUNDS[:, 1].copy()

    def __init__(self, cell: Workcell, block_gripper: bool = False) -> None:
        self.block_gripper = block_gripper
        self.space = gym.spaces.Box(-1.0, 1.0, (3 if block_gripper else 4,), dtype=np.float32)
        #: Steers the hand; its goal is the mode's target, integrated from the actions.
        self.servo = JacobianServo(cell.model, cell.data)

    @classmethod
    def build(cls, context: ActionContext) -> EEDeltaActions:
        return cls(context.cell, context.block_gripper)

    def reset(self, cell: Workcell, rng: np.random.Generator) -> None:
        self.servo.set_goal(cell.robot.ee_position, HOME_YAW)

    def execute(self, cell: Workcell, action: np.ndarray) -> None:
        # The target integrates the commanded displacements (so a zero action holds the hand where it
        # was told to be), but never runs more than MAX_LAG ahead of the hand horizontally (pushing against
        # something).  Heights need no such limit (the target stays above the table), and clamping them
        # too would copy the hand's height error into the target during fast horizontal moves.
        target = self.servo.goal_position
        lag = target[:2] - cell.robot.ee_position[:2]
        distance = float(np.sqrt(lag @ lag))
        if distance > self.MAX_LAG:
            target[:2] = cell.robot.ee_position[:2] + lag * (self.MAX_LAG / distance)
        self.servo.set_goal(np.minimum(np.maximum(target + action[:3] * EE_STEP, self.LOW), self.HIGH), HOME_YAW)
        closing = 1.0 if self.block_gripper else float(action[3])
        cell.robot.command_fingers(FINGER_OPEN * (1.0 - closing) / 2.0)
        cell.physics.control_step(self.servo)
        return None


class JointActions(ActionMode):
    """``Box(8)`` in [-1, 1]: arm joint-position deltas x ``JOINT_STEP`` radians (7) and gripper (as ee_delta)."""

    name = "joint"
    low_level = True

    def __init__(self) -> None:
        self.space = gym.spaces.Box(-1.0, 1.0, (8,), dtype=np.float32)

    @classmethod
    def build(cls, context: ActionContext) -> JointActions:
        return cls()

    def execute(self, cell: Workcell, action: np.ndarray) -> None:
        targets = JointTargets(cell.robot.joint_positions + action[:7] * JOINT_STEP)
        cell.robot.command_fingers(FINGER_OPEN * (1.0 - action[7]) / 2.0)
        cell.physics.control_step(targets)
        return None


class GraspPoseActions(ActionMode):
    """``Box(-1, 1, (7,))``: a 6-DOF grasp -- grasp-site x, y over the workspace, z over 0-0.3 m, then an
    orientation quaternion (w, x, y, z; normalised here, must not be zero) with x = closing axis and
    z = approach direction -- executed by the motion stack (IK with tolerance, OMPL plan, approach,
    close, retreat, lift, verify)."""

    name = "grasp_pose"
    low_level = False

    def __init__(self, stack: MotionStack) -> None:
        self.stack = stack
        self.space = gym.spaces.Box(-1.0, 1.0, (7,), dtype=np.float32)

    @classmethod
    def build(cls, context: ActionContext) -> GraspPoseActions:
        from panda_grasp_env.primitives.pose_grasp import MotionStack  # OMPL loads only when this mode is used

        return cls(MotionStack(context.cell, planner=context.planner))

    def layout(self) -> dict[str, Any]:
        return {"mode": self.name}

    def reset(self, cell: Workcell, rng: np.random.Generator) -> None:
        self.stack.reseed(int(rng.integers(2**31)))  # the planner's samples follow the episode seed

    def validate(self, action: Any) -> tuple[np.ndarray, int]:
        array, clipped = validate_box_action(action, self.space)
        if np.linalg.norm(array[3:]) < 1e-6:
            raise ValueError(
                f"grasp_pose action: the quaternion (entries 3-6) must not be zero, got {array[3:].tolist()}"
            )
        return array, clipped

    def decode(self, action: np.ndarray) -> PoseGraspParameters:
        """The grasp pose of a validated action."""
        quaternion = action[3:] / np.linalg.norm(action[3:])
        rotation = np.zeros(9)
        mujoco.mju_quat2Mat(rotation, quaternion)
        return PoseGraspParameters(to_world(action[:3]), rotation.reshape(3, 3))

    def execute(self, cell: Workcell, action: np.ndarray) -> PrimitiveResult:
        return self.stack.grasp(cell, self.decode(action))


def encode_grasp_pose(position: np.ndarray, rotation: np.ndarray) -> np.ndarray:
    """A ``grasp_pose``-mode action for the grasp site at ``position`` (world, metres) with ``rotation`` (3, 3)."""
    quaternion = np.zeros(4)
    mujoco.mju_mat2Quat(quaternion, np.asarray(rotation, dtype=float).ravel())
    return np.array([*to_normalised(position[:3]), *quaternion], dtype=np.float32)


#: Every action mode by name.
ACTION_MODES: dict[str, type[ActionMode]] = {
    mode.name: mode
    for mode in (PrimitiveActions, PixelActions, FactoredPixelActions, EEDeltaActions, JointActions, GraspPoseActions)
}
