"""Motion of the grasp site in the live simulation: straight-line Cartesian moves through the workcell's
control step, transits above everything in the way, the way home, and teleporting the hand for resets
(IK with no physics time passing).  World frame, metres, radians.
"""

from __future__ import annotations

from collections.abc import Callable, Iterator
from contextlib import contextmanager
from dataclasses import dataclass
from typing import Any, Protocol

import mujoco
import numpy as np

from panda_grasp_env.control.controller import CartesianController, JointTargets
from panda_grasp_env.model.robot import FINGERTIP_DEPTH, HOME_POSITION, HOME_QPOS, HOME_YAW, PandaRobot
from panda_grasp_env.sim.collateral import CollateralMonitor
from panda_grasp_env.sim.extents import body_vertical_extent
from panda_grasp_env.sim.fixtures import Fixtures
from panda_grasp_env.sim.parts import OwnerReference
from panda_grasp_env.sim.stepping import Physics

#: Reachable region for primitive targets: x, y, z bounds of the grasp site, metres.
WORKSPACE = np.array([[0.25, 0.75], [-0.35, 0.35], [0.0, 0.45]])
#: Transit: the lowest point of the hand (fingertips, 15 mm below the grasp site) or of the object it carries
#: crosses this far above the tallest object, metres; and the grasp site never lower than TRANSIT_MIN_HEIGHT.
TRANSIT_CLEARANCE = 0.03
TRANSIT_MIN_HEIGHT = 0.12
#: Reset IK solutions kept (least recently used dropped first).
TELEPORT_CACHE_SIZE = 64


@dataclass
class MoveOutcome:
    """How a Cartesian move of the grasp site ended: within tolerance of its goal or not, and how far off."""

    reached: bool
    #: Distance between the grasp site and the goal when the move ended, metres.
    error: float


class MovingCell(Protocol):
    """What motion reads and drives of a workcell (``Workcell`` is one; it owns its motion, so no import of it)."""

    model: mujoco.MjModel
    data: mujoco.MjData
    robot: PandaRobot
    controller: CartesianController
    physics: Physics[Any]
    collateral: CollateralMonitor
    fixtures: Fixtures
    object_ids: np.ndarray

    def is_parked(self, body_id: int) -> bool: ...


class Motion:
    """Moves the grasp site of ``cell``: every step through its ``physics.control_step`` with its Cartesian
    controller (or joint targets, on the way home)."""

    #: The workcell that owns this part, held weakly (``sim.parts``).
    cell: OwnerReference[MovingCell] = OwnerReference()

    def __init__(self, cell: MovingCell) -> None:
        self.cell = cell
        self.model, self.data, self.robot, self.controller = cell.model, cell.data, cell.robot, cell.controller
        self.physics, self.collateral = cell.physics, cell.collateral
        self._scratch = mujoco.MjData(cell.model)  # kinematics checks that must not touch the live state
        self._teleport_solutions: dict[tuple, np.ndarray] = {}

    def move_to(
        self,
        position: np.ndarray,
        yaw: float,
        speed: float | None = None,
        tolerance: float = 0.004,
        settle_timeout: float = 1.0,
        stop_when: Callable[[], bool] | None = None,
    ) -> MoveOutcome:
        """Drive the grasp site in a straight line to ``position`` with closing-axis heading ``yaw``.

        The reference moves at ``speed`` m/s (default and cap: the controller's limit).
        Returns once within ``tolerance`` metres of the goal at rest, after the
        settle timeout, or as soon as ``stop_when()`` is true -- or, in a primitive's
        work segment, as soon as the robot first touches a fixture the primitive was not
        aimed at (a protective stop; ``collateral``).
        """
        self.controller.set_goal(position, yaw, speed)
        goal = self.controller.goal_position
        travel_steps = int(np.ceil(self.controller.time_to_goal / self.physics.control_dt))
        settle_steps = int(np.ceil(settle_timeout / self.physics.control_dt))
        for i in range(travel_steps + 4 + settle_steps):
            self.physics.control_step(self.controller)
            if self.collateral.new_fixture_hit or (stop_when is not None and stop_when()):
                self.controller.stop()  # don't keep driving towards the goal after stopping
                break
            error = float(np.linalg.norm(self.robot.ee_position - goal))
            if i >= travel_steps and error < tolerance and np.abs(self.robot.joint_velocities).max() < 0.05:
                break
        error = float(np.linalg.norm(self.robot.ee_position - goal))
        return MoveOutcome(reached=error < tolerance, error=error)

    @contextmanager
    def one_heading(self, *points: np.ndarray) -> Iterator[None]:
        """Within the block every move turns the hand to the same half-turn branch of its goal heading: the one
        that puts joint 7 mid-range over the centre of ``points`` (world, metres), chosen once.  A primitive
        runs in one so that its hand does not turn half a revolution between goals whose own joint-7 windows
        differ (a push stroke across the line where they meet did)."""
        previous = self.controller.heading_window_at
        self.controller.heading_window_at = np.mean([np.asarray(p, dtype=float)[:2] for p in points], axis=0)
        try:
            yield
        finally:
            self.controller.heading_window_at = previous

    def tallest_top(self, exclude: int | None = None, near: tuple[float, float, float] | None = None) -> float:
        """Highest top (world z, metres; 0 if none) of the objects on the table and the fixtures, leaving out
        ``exclude`` and, with ``near`` = (x, y, radius), everything whose footprint stays further than radius
        from (x, y)."""
        tops = [
            top
            for x, y, reach, top in self.cell.fixtures.tops
            if near is None or np.hypot(x - near[0], y - near[1]) < near[2] + reach
        ]
        tops.append(0.0)
        for b in map(int, self.cell.object_ids):
            if b == exclude or self.cell.is_parked(b):
                continue
            reach = self.model.geom_rbound[self.model.body_geomadr[b]]
            if near is not None and np.hypot(*(self.data.xpos[b][:2] - near[:2])) >= near[2] + reach:
                continue
            tops.append(body_vertical_extent(self.model, self.data, b)[1])
        return max(tops)

    def transit_height(self) -> float:
        """Grasp-site height (metres) at which the hand, and whatever it carries, clears every object on the
        table by ``TRANSIT_CLEARANCE``; at least ``TRANSIT_MIN_HEIGHT``, at most the workspace's top."""
        held = self.robot.body_between_fingers()
        hang = FINGERTIP_DEPTH
        if held is not None:
            hang = max(hang, self.robot.ee_position[2] - body_vertical_extent(self.model, self.data, held)[0])
        height = self.tallest_top(exclude=held) + TRANSIT_CLEARANCE + hang
        return float(min(max(height, TRANSIT_MIN_HEIGHT), WORKSPACE[2, 1]))

    def clear_height_near(self, x: float, y: float, radius: float = 0.12) -> float:
        """Grasp-site height (metres) at which the empty hand over (x, y) clears, by ``TRANSIT_CLEARANCE``, every
        object whose footprint comes within ``radius`` of (x, y) (the hand's half-span)."""
        return self.tallest_top(near=(x, y, radius)) + TRANSIT_CLEARANCE + FINGERTIP_DEPTH

    def rise(self, height: float | None = None) -> None:
        """Straight up to ``height`` (default: the transit height), if the grasp site is lower."""
        height = self.transit_height() if height is None else height
        position = self.robot.ee_position
        if position[2] < height - 0.005:
            self.move_to(np.array([*position[:2], height]), self.robot.ee_yaw, settle_timeout=0.2, tolerance=0.02)

    def transit(self, x: float, y: float, yaw: float) -> MoveOutcome:
        """Travel to (x, y) at the transit height, the hand turned to ``yaw``: straight up first, then in a
        straight line, which never dips below the transit height since it starts at or above it (home is
        higher than any transit height)."""
        height = self.transit_height()
        self.rise(height)
        return self.move_to(np.array([x, y, height]), yaw, tolerance=0.01)

    def _joint_line_stays_above(self, goal: np.ndarray, height: float, samples: int = 12) -> bool:
        """Whether the grasp site stays at least ``height`` (metres) high all along the straight joint-space
        line from the arm's current joints to ``goal`` (the hand is the robot's lowest part there)."""
        scratch = self._scratch
        scratch.qpos[:] = self.data.qpos
        start = self.robot.joint_positions
        for fraction in np.linspace(0.0, 1.0, samples + 1)[1:]:
            scratch.qpos[self.robot.arm_qpos_idx] = start + fraction * (goal - start)
            mujoco.mj_kinematics(self.model, scratch)
            if scratch.site_xpos[self.robot.site_id][2] < height:
                return False
        return True

    def move_home(self, joint_speed: float = 1.2) -> None:
        """Back to the home configuration without sweeping through the scene: straight up to the transit
        height, then a joint-space move at ``joint_speed`` rad/s onto the home joint angles if the hand stays
        above the transit height all along it, else across to the home position in a straight line first
        (home is higher than any transit); settle."""
        height = self.transit_height()
        self.rise(height)
        if not self._joint_line_stays_above(HOME_QPOS, height - 0.01):
            self.move_to(HOME_POSITION, HOME_YAW, settle_timeout=0.2, tolerance=0.03)
        start = self.robot.joint_positions
        n = max(1, int(np.ceil(np.abs(HOME_QPOS - start).max() / (joint_speed * self.physics.control_dt))))
        for fraction in np.linspace(0.0, 1.0, n + 1)[1:]:
            self.physics.control_step(JointTargets(start + fraction * (HOME_QPOS - start)))
        for _ in range(int(0.6 / self.physics.control_dt)):
            if np.abs(self.robot.joint_positions - HOME_QPOS).max() < 0.01:
                break
            self.physics.control_step(None)  # the servos keep the home targets
        self.controller.sync(self.robot.joint_positions)

    def teleport_hand(self, position: np.ndarray, yaw: float, max_iterations: int = 300) -> float:
        """Put the arm, at rest, in the configuration that holds the grasp site at ``position`` with heading ``yaw``.

        Solves the IK on its own (no physics time passes); for resets.  Returns
        the remaining position error, metres.
        """
        # The IK is deterministic, so each (start, goal) is solved once; goals are rounded to 0.1 mm
        # first, so the answer never depends on which nearby goal came first.
        position = np.round(np.asarray(position, dtype=float), 4)
        yaw = round(float(yaw), 4)
        start = self.robot.joint_positions
        key = (*position, yaw, *start)
        solution = self._teleport_solutions.pop(key, None)
        if solution is None:
            self.controller.sync(start)
            self.controller.set_goal(position, yaw)
            for _ in range(max_iterations):
                self.controller.step(self.physics.control_dt)
                if self.controller.converged:
                    break
            solution = self.controller.commanded_qpos
            if len(self._teleport_solutions) >= TELEPORT_CACHE_SIZE:
                del self._teleport_solutions[next(iter(self._teleport_solutions))]  # least recently used
        self._teleport_solutions[key] = solution
        self.data.qpos[self.robot.arm_qpos_idx] = solution
        self.data.qvel[self.robot.arm_qvel_idx] = 0.0
        self.robot.command_joints(solution)
        mujoco.mj_forward(self.model, self.data)
        self.controller.sync(self.robot.joint_positions)
        return float(np.linalg.norm(self.robot.ee_position - position))
