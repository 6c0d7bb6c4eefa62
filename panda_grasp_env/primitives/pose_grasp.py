"""Executing a 6-DOF grasp pose: IK with tolerance, collision-free plan, approach, close, retreat, lift, verify.

The motion stack joins ``control.ik`` (pose IK, tolerance sampler) and ``control.planning``
(OMPL, trajectory timing) on a live :class:`~panda_grasp_env.sim.workcell.Workcell`:

1. IK for the grasp pose (tolerance sampler) and for the pre-grasp pose 10 cm
   back along the approach axis;
2. a collision-free path from the current joints to the pre-grasp
   configuration around the scene as it is now, timed by ruckig;
3. the approach: a straight joint-space line to the grasp configuration, slowly;
4. close, retreat to the pre-grasp configuration, lift 10 cm straight up, hold;
5. verify as the top-down grasp primitive does (held by both fingers, risen >= 5 cm).

Failures say where they happened: ``no_ik_solution``, ``no_plan``, ``missed``,
``dropped`` (or ``physics_error``); after one the arm opens and goes home.
"""

from __future__ import annotations

import numpy as np

from panda_grasp_env.control.controller import JointTargets
from panda_grasp_env.control.ik import PoseIK, ToleranceSampler
from panda_grasp_env.control.planning import MotionPlanner, time_parametrise
from panda_grasp_env.primitives.parameters import PoseGraspParameters
from panda_grasp_env.primitives.result import HOLD_TIME, PrimitiveResult, closed_on, lifted_and_held, run_motion
from panda_grasp_env.sim.workcell import Workcell

PRE_GRASP = 0.10  # metres back along the approach axis
LIFT = 0.10  # metres straight up after the retreat
#: Share of the Panda's joint speed limits used for planned motions, and for the slow approach.
TRANSIT_SPEED, APPROACH_SPEED = 0.5, 0.15


class MotionStack:
    """IK, planner and timing for one workcell; ``grasp`` executes a 6-DOF grasp pose on it.  Its waits keep
    the arm's joint targets (``keep_joint_targets``): the Cartesian controller would turn the hand top-down."""

    def __init__(self, cell: Workcell, planner: str = "RRTConnect", seed: int = 0, time_limit: float = 2.0) -> None:
        self.ik = PoseIK(cell.config)
        self.sampler = ToleranceSampler()
        self.planner = MotionPlanner(cell.config, planner=planner, seed=seed)
        self.time_limit = time_limit
        self.rng = np.random.default_rng(seed)
        self.max_velocity = np.asarray(cell.controller.limits.joint_speed)

    def reseed(self, seed: int) -> None:
        """IK restarts and the planner's queries draw from generators reseeded at every env reset (episodes
        repeat, in any order)."""
        self.rng = np.random.default_rng(seed)
        self.planner.reseed(seed)

    def _follow(self, cell: Workcell, targets: np.ndarray) -> None:
        for target in targets:
            cell.physics.control_step(JointTargets(target))
        for _ in range(int(0.5 / cell.physics.control_dt)):  # settle on the last target
            if np.abs(cell.robot.joint_velocities).max() < 0.05:
                break
            cell.physics.control_step(None)

    def _fail(self, cell: Workcell, reason: str, retreat: tuple[np.ndarray, np.ndarray] | None, obj: str | None = None):
        """Open, back out along the approach, go home; report ``reason``."""
        cell.actuate_gripper(close=False, keep_joint_targets=True)
        if retreat is not None:
            self._follow(cell, self._line(cell, *retreat, APPROACH_SPEED))
        cell.motion.move_home()
        return PrimitiveResult("grasp", False, reason, object=obj)

    def _line(self, cell: Workcell, start: np.ndarray, end: np.ndarray, speed: float) -> np.ndarray:
        return time_parametrise(np.array([start, end]), self.max_velocity * speed, cell.physics.control_dt)

    def grasp(self, cell: Workcell, parameters: PoseGraspParameters) -> PrimitiveResult:
        """Grasp with the grasp site at ``parameters.position`` (world, metres) and orientation
        ``parameters.rotation`` (3, 3), through ``run_motion`` as every primitive."""
        return run_motion(cell, parameters, self._motion)

    def _motion(self, cell: Workcell, parameters: PoseGraspParameters) -> PrimitiveResult:
        result = self._grasp(cell, parameters.position, parameters.rotation)
        if result.object is not None:
            result.targets = {cell.model.body(result.object).id}
        return result

    def _grasp(self, cell: Workcell, position: np.ndarray, rotation: np.ndarray) -> PrimitiveResult:
        current = cell.robot.joint_positions
        at_grasp = None
        # A parallel gripper is symmetric under a half turn about its approach axis: try both hands.
        for hand in (rotation, rotation @ np.diag([-1.0, -1.0, 1.0])):
            at_grasp, _ = self.sampler.solve(self.ik, position, hand, current, self.rng)
            if at_grasp is not None:
                break
        if at_grasp is None:
            return PrimitiveResult("grasp", False, "no_ik_solution")
        approach = at_grasp.rotation[:, 2]
        at_pre = self.ik.solve(position - PRE_GRASP * approach, at_grasp.rotation, at_grasp.qpos, self.rng)
        lifted = position - PRE_GRASP * approach + [0.0, 0.0, LIFT]
        at_lift = None if at_pre is None else self.ik.solve(lifted, at_grasp.rotation, at_pre.qpos, self.rng)
        if at_pre is None or at_lift is None:
            return PrimitiveResult("grasp", False, "no_ik_solution")
        self.planner.sync_objects(cell.model, cell.data, cell.object_names)
        self.planner.sync_fixtures(cell.model)
        plan = self.planner.plan(current, at_pre.qpos, self.time_limit)
        if not plan.success:
            return PrimitiveResult("grasp", False, "no_plan")
        cell.actuate_gripper(close=False, keep_joint_targets=True)
        self._follow(cell, time_parametrise(plan.path, self.max_velocity * TRANSIT_SPEED, cell.physics.control_dt))
        with cell.collateral.work():  # approach, close, retreat, lift: the rest (planned path, home) is transit
            return self._close_and_lift(cell, at_grasp.qpos, at_pre.qpos, at_lift.qpos)

    def _close_and_lift(
        self, cell: Workcell, at_grasp: np.ndarray, at_pre: np.ndarray, at_lift: np.ndarray
    ) -> PrimitiveResult:
        self._follow(cell, self._line(cell, at_pre, at_grasp, APPROACH_SPEED))
        cell.actuate_gripper(close=True, keep_joint_targets=True)
        body = closed_on(cell)
        if body is None:
            return self._fail(cell, "missed", (cell.robot.joint_positions, at_pre))
        start_height = cell.data.xpos[body][2]
        self._follow(cell, self._line(cell, at_grasp, at_pre, APPROACH_SPEED))
        self._follow(cell, self._line(cell, at_pre, at_lift, TRANSIT_SPEED))
        cell.wait(HOLD_TIME, keep_joint_targets=True)
        cell.controller.sync(cell.robot.joint_positions)  # later primitives start from here
        if not lifted_and_held(cell, body, start_height):
            return self._fail(cell, "dropped", None, cell.name_of(body))
        return PrimitiveResult("grasp", True, "ok", object=cell.name_of(body))
