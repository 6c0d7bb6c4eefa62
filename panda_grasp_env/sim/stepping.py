"""Stepping one MuJoCo simulation: control steps at the control rate, divergence checks, per-step observers.

A control step sets the arm's joint targets from a controller (any ``JointController``: the Cartesian
controller, the Jacobian servo, fixed joint targets) and runs ``control_substeps`` physics steps.  After every
physics advance the step is checked (MuJoCo's bad-state warnings, objects thrown faster than
``MAX_OBJECT_SPEED``) and the registered observers (``StepObserver``) are called with the workcell, in the
order they were added.  The workcell adds its collateral monitor first; everything else is added from above
(the env its task's ``on_control_step`` and its video capture, tooling its recorders): this module imports
nothing of theirs.
"""

from __future__ import annotations

from collections.abc import Callable, Iterator
from contextlib import contextmanager
from typing import Generic, TypeVar

import mujoco
import numpy as np

from panda_grasp_env.control.controller import JointController
from panda_grasp_env.geometry import is_count
from panda_grasp_env.model.robot import PandaRobot
from panda_grasp_env.sim.parts import OwnerReference

#: MuJoCo's bad-state warnings, consecutive in mjtWarning: BADQPOS, BADQVEL, BADQACC.
_WARNINGS = slice(int(mujoco.mjtWarning.mjWARN_BADQPOS), int(mujoco.mjtWarning.mjWARN_BADQACC) + 1)

#: No free object here moves faster than this (m/s) unless the contact solver threw it: a fall from the table
#: top to the floor reaches 3.8 m/s and the arm's fastest motion under 2 m/s, while cubes thrown by a wrong
#: Newton solve (MuJoCo 4.0.0's sparse factorisation, see ``model.scene``) left at 18-64 m/s.
MAX_OBJECT_SPEED = 8.0

#: What observers are handed after each step: the workcell that owns the stepping.
Cell = TypeVar("Cell")
#: Called with the workcell after every control step, inside primitives too (and after an impulse's short
#: push): a task's timers, video capture, a recorder.
StepObserver = Callable[[Cell], None]


class PhysicsError(RuntimeError):
    """The simulation diverged (MuJoCo warning or non-finite state) or threw an object (``MAX_OBJECT_SPEED``)."""


def body_speeds(data: mujoco.MjData, body_ids: np.ndarray) -> np.ndarray:
    """Speeds (n,) of the bodies' centres of mass, m/s, world frame, as of the last step."""
    return np.linalg.norm(data.cvel[body_ids, 3:], axis=1)


class Physics(Generic[Cell]):
    """The stepping of ``cell``'s simulation (``model``, ``data``): ``control_substeps`` physics steps make one
    control step (default 20 x 2 ms = 25 Hz, the rate of the env's low-level action modes); ``object_ids``
    are the free bodies whose speed is checked."""

    #: The workcell that owns this part, held weakly (``sim.parts``).
    cell: OwnerReference[Cell] = OwnerReference()

    def __init__(
        self,
        cell: Cell,
        model: mujoco.MjModel,
        data: mujoco.MjData,
        robot: PandaRobot,
        object_ids: np.ndarray,
        control_substeps: int = 20,
    ) -> None:
        if not is_count(control_substeps) or control_substeps < 1:
            raise ValueError(f"control_substeps must be a positive int, got {control_substeps!r}")
        self.cell, self.model, self.data, self.robot, self.object_ids = cell, model, data, robot, object_ids
        self.control_substeps = control_substeps
        #: Seconds of simulated time per control step.
        self.control_dt = control_substeps * model.opt.timestep
        #: Physics steps since the clock last restarted (the workcell's ``clear`` and ``settle``).
        self.steps = 0
        #: Objects faster than this (m/s) end the step with ``PhysicsError``; see ``allowing_object_speed``.
        self.max_object_speed = MAX_OBJECT_SPEED
        self._observers: list[StepObserver[Cell]] = []

    def add_observer(self, observer: StepObserver[Cell]) -> None:
        """Call ``observer(cell)`` after every step from now on, after the observers added before it."""
        self._observers.append(observer)

    def remove_observer(self, observer: StepObserver[Cell]) -> None:
        """Stop calling ``observer`` (``ValueError`` if it was not added)."""
        self._observers.remove(observer)

    @property
    def observers(self) -> tuple[StepObserver[Cell], ...]:
        """The observers, in the order they are called."""
        return tuple(self._observers)

    def step(self, n_steps: int) -> None:
        """Advance the physics ``n_steps`` steps with the current controls; raise PhysicsError on divergence."""
        mujoco.mj_step(self.model, self.data, nstep=n_steps)
        self.steps += n_steps
        # MuJoCo's own checks catch NaN/inf and runaway values (and reset the data when they fire).
        if np.count_nonzero(self.data.warning.number[_WARNINGS]):
            raise PhysicsError("simulation diverged (MuJoCo reported bad qpos/qvel/qacc)")
        fastest = float(body_speeds(self.data, self.object_ids).max(initial=0.0))
        if fastest > self.max_object_speed:
            raise PhysicsError(
                f"the contact solver threw an object at {fastest:.1f} m/s "
                f"(no object here moves faster than {self.max_object_speed:g} m/s)"
            )
        for observer in self._observers:
            observer(self.cell)

    def control_step(self, controller: JointController | None) -> None:
        """One control step: the arm's joint targets from ``controller`` (advanced by ``control_dt``; None: the
        servos keep their targets), then ``control_substeps`` physics steps."""
        if controller is not None:
            self.robot.command_joints(controller.step(self.control_dt))
        self.step(self.control_substeps)

    @contextmanager
    def allowing_object_speed(self, speed: float) -> Iterator[None]:
        """Let objects move at up to ``speed`` m/s (when faster than ``MAX_OBJECT_SPEED``) inside the block: an
        impulse's own push is not a solver fault."""
        before = self.max_object_speed
        self.max_object_speed = max(before, float(speed))
        try:
            yield
        finally:
            self.max_object_speed = before
