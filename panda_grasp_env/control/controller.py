"""Controllers: what sets the arm's joint targets at each control step (``JointController``).

``CartesianController`` drives the grasp site to a target pose at bounded speed (the primitives);
``JacobianServo`` takes one closed-loop step towards a target per control step (``ee_delta``);
``JointTargets`` holds fixed joint targets (``joint``, joint-space moves).

The Cartesian controller's choice: differential inverse kinematics with ``mink`` on a robot-only model
compiled from the same spec as the simulation (identical kinematics), feeding
the arm's joint position servos.  Compared with an operational-space controller
it needs no accurate dynamics model, respects joint limits as hard QP
constraints, keeps the elbow near a posture through a low-weight posture task,
and costs one small QP per control step (~70 us with daqp), so physics, not
Python, dominates a control step.

The controller integrates its own commanded configuration (a reference, not the
measured joints) so servo lag never feeds back into the IK; ``sync`` re-seeds it
from the measured joints at the start of every motion.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Protocol

import mink
import mujoco
import numpy as np

from panda_grasp_env.geometry import top_down_rotation
from panda_grasp_env.model.robot import HOME_QPOS
from panda_grasp_env.model.scene import ARM_JOINTS, GRASP_SITE, SceneConfig, build_spec

#: Joint speed (rad/s) below which the IK solution counts as converged for a fixed reference.
REST_SPEED = 1e-3
#: Bounds on the memo of IK solves while holding still at home after a ``sync``: configurations remembered
#: (the home arm with the fingers' IK coordinates as earlier holds left them), and solves remembered per
#: configuration (a hold from home converges in a few).
HOLD_MEMO_STARTS, HOLD_MEMO_STEPS = 8, 32


class JointController(Protocol):
    """Anything that gives the arm's joint targets for a control step (the workcell's ``physics.control_step``)."""

    def step(self, dt: float) -> np.ndarray:
        """Advance by ``dt`` seconds; the arm's joint position targets (7,), radians."""


@dataclass
class JointTargets:
    """Fixed arm joint position targets (7,), radians: the ``joint`` action mode and joint-space moves."""

    qpos: np.ndarray

    def step(self, dt: float) -> np.ndarray:
        """The targets, whatever ``dt``."""
        return self.qpos


@dataclass
class ControllerLimits:
    """Speed bounds of the commanded end-effector motion."""

    linear_speed: float = 0.35  # m/s
    angular_speed: float = 2.0  # rad/s
    #: Joint speed caps handed to the IK, rad/s: the Panda's datasheet limits (joints 1-4, 5-7).
    joint_speed: tuple[float, ...] = (2.175, 2.175, 2.175, 2.175, 2.61, 2.61, 2.61)


def gripper_yaw_window_centre(position: np.ndarray) -> float:
    """Gripper yaw that puts joint 7 mid-range with the hand over ``position`` (x, y in metres).

    For a top-down hand, yaw ~= q1 - pi/2 - q7 and q1 ~= atan2(y, x).
    """
    return float(-np.pi / 2 + np.arctan2(position[1], position[0]))


def wrap_gripper_yaw(yaw: float, position: np.ndarray) -> float:
    """Equivalent gripper yaw (mod pi) within +-pi/2 of the joint-7-centred heading at ``position``."""
    centre = gripper_yaw_window_centre(position)
    return float((yaw - centre + np.pi / 2) % np.pi - np.pi / 2 + centre)


class CartesianController:
    """Differential IK (mink) from a target grasp-site pose to arm joint targets."""

    def __init__(self, scene_config: SceneConfig, limits: ControllerLimits | None = None) -> None:
        self.limits = limits or ControllerLimits()
        self.ik_model = build_spec(scene_config, with_environment=False).compile()
        self.configuration = mink.Configuration(self.ik_model)
        self._arm_idx = np.array([self.ik_model.jnt_qposadr[self.ik_model.joint(n).id] for n in ARM_JOINTS])
        self.frame_task = mink.FrameTask(GRASP_SITE, "site", position_cost=1.0, orientation_cost=0.5, lm_damping=1e-3)
        self.posture_task = mink.PostureTask(self.ik_model, cost=1e-2)
        q_home = self.configuration.q.copy()
        q_home[self._arm_idx] = HOME_QPOS
        self.posture_task.set_target(q_home)
        self.ik_limits = [
            mink.ConfigurationLimit(self.ik_model, gain=0.9),
            mink.VelocityLimit(self.ik_model, dict(zip(ARM_JOINTS, self.limits.joint_speed))),
        ]
        self.reference_position = np.zeros(3)
        self.reference_yaw = 0.0
        self.goal_position = np.zeros(3)
        self.goal_yaw = 0.0
        #: Where goal headings pick their joint-7 window (world x, y metres); None: at each goal.
        self.heading_window_at: np.ndarray | None = None
        self.goal_speed = self.limits.linear_speed
        #: Whether the last IK step barely moved: with an unchanged reference, further solves are skipped.
        self._at_rest = False
        # Holding still right after a sync is a pure function of the synced configuration and dt (the IK
        # never reads the simulation), and every reset holds at home while the scene settles: those solves
        # are remembered and replayed bit for bit instead of re-solving the QP.
        self._hold_start: bytes | None = None  # the synced configuration, while holding at home since the sync
        self._hold_solves = 0  # solves (made or replayed) since that sync
        self._hold_memo: dict[tuple[bytes, float], list[tuple[np.ndarray, bool]]] = {}

    def sync(self, arm_qpos: np.ndarray) -> None:
        """Re-seed the commanded configuration and reference pose from measured joints."""
        q = self.configuration.q.copy()
        q[self._arm_idx] = arm_qpos
        self.configuration.update(q)
        pose = self.configuration.get_transform_frame_to_world(GRASP_SITE, "site")
        self.reference_position = pose.translation().copy()
        x_axis = pose.rotation().as_matrix()[:, 0]
        heading = float(np.arctan2(x_axis[1], x_axis[0]))
        # Unwrap the heading (mod 2 pi) to agree with the joint angles, so yaw
        # interpolation turns joint 7 the short way and never into its limit.
        expected = arm_qpos[0] - np.pi / 2 - arm_qpos[6]
        self.reference_yaw = heading + 2 * np.pi * round((expected - heading) / (2 * np.pi))
        self.goal_position = self.reference_position.copy()
        self.goal_yaw = self.reference_yaw
        self._at_rest = False
        self._hold_start = self.configuration.q.tobytes() if np.array_equal(arm_qpos, HOME_QPOS) else None
        self._hold_solves = 0

    def set_goal(self, position: np.ndarray, yaw: float, speed: float | None = None) -> None:
        """New goal: grasp site at ``position`` (world, metres), pointing down, closing axis at ``yaw``.

        The reference travels there at ``speed`` m/s (default and cap: ``limits.linear_speed``).
        A parallel gripper is symmetric under a half turn, so ``yaw`` is wrapped
        into the half-turn window that keeps joint 7 near the middle of its range
        with the hand over the goal -- or over ``heading_window_at`` while a
        motion holds one heading through several goals (``Motion.one_heading``).
        """
        self.goal_position = np.asarray(position, dtype=float).copy()
        window = self.goal_position if self.heading_window_at is None else self.heading_window_at
        self.goal_yaw = wrap_gripper_yaw(yaw, window)
        self.goal_speed = self.limits.linear_speed if speed is None else min(speed, self.limits.linear_speed)
        self._hold_start = None

    def stop(self) -> None:
        """Make the current reference the goal: the hand stays where it is commanded now."""
        self.goal_position = self.reference_position.copy()
        self.goal_yaw = self.reference_yaw
        self._hold_start = None

    @property
    def time_to_goal(self) -> float:
        """Seconds the speed-limited reference still needs to reach the goal."""
        return max(
            self.reference_error / self.goal_speed, abs(self.goal_yaw - self.reference_yaw) / self.limits.angular_speed
        )

    @property
    def commanded_qpos(self) -> np.ndarray:
        return self.configuration.q[self._arm_idx].copy()

    @property
    def reference_error(self) -> float:
        """Distance between the speed-limited reference and the goal, metres."""
        return float(np.linalg.norm(self.goal_position - self.reference_position))

    def step(self, dt: float) -> np.ndarray:
        """Advance the reference by ``dt`` seconds towards the goal and return arm joint targets (7,)."""
        offset = self.goal_position - self.reference_position
        distance = math.sqrt(offset @ offset)
        max_step = self.goal_speed * dt
        if distance > max_step:
            offset *= max_step / distance
        holding = distance == 0.0 and self.goal_yaw == self.reference_yaw
        if holding and self._at_rest:
            return self.commanded_qpos  # holding still: the last solution stands, no QP needed
        memo = self._hold_solutions(dt) if holding else None
        if memo is not None and self._hold_solves < len(memo):
            q, self._at_rest = memo[self._hold_solves]
            self.configuration.update(q)
            self._hold_solves += 1
            return self.commanded_qpos
        self.reference_position = self.reference_position + offset
        max_turn = self.limits.angular_speed * dt
        self.reference_yaw += float(np.clip(self.goal_yaw - self.reference_yaw, -max_turn, max_turn))
        rotation = mink.SO3.from_matrix(top_down_rotation(self.reference_yaw))
        target = mink.SE3.from_rotation_and_translation(rotation, self.reference_position)
        self.frame_task.set_target(target)
        velocity = mink.solve_ik(
            self.configuration, [self.frame_task, self.posture_task], dt, "daqp", damping=1e-4, limits=self.ik_limits
        )
        self.configuration.integrate_inplace(velocity, dt)
        self._at_rest = float(np.abs(velocity).max()) < REST_SPEED
        if memo is not None:
            if self._hold_solves == len(memo) < HOLD_MEMO_STEPS:
                memo.append((self.configuration.q.copy(), self._at_rest))
            self._hold_solves += 1
        return self.commanded_qpos

    def _hold_solutions(self, dt: float) -> list[tuple[np.ndarray, bool]] | None:
        """The remembered (configuration, at rest) of each solve of the current hold at home, or None when
        not holding at home since a sync (or the memo is full)."""
        if self._hold_start is None:
            return None
        key = (self._hold_start, dt)
        if key not in self._hold_memo and len(self._hold_memo) < HOLD_MEMO_STARTS:
            self._hold_memo[key] = []
        return self._hold_memo.get(key)

    @property
    def converged(self) -> bool:
        """The reference is at the goal and the IK has stopped moving."""
        return self.reference_error == 0.0 and self.goal_yaw == self.reference_yaw and self._at_rest

    def tracking_error(self) -> float:
        """Position error of the IK's own solution against its reference, metres."""
        pose = self.configuration.get_transform_frame_to_world(GRASP_SITE, "site")
        return float(np.linalg.norm(pose.translation() - self.reference_position))


class JacobianServo:
    """Damped-least-squares differential IK, one step per control step, on the simulation's own model.

    The low-level ``ee_delta`` mode moves the target at most a few centimetres
    per 40 ms step, so one closed-loop Jacobian step from the *measured* joints
    is enough; it costs ~20 us against ~70 us for a constrained mink QP, which
    matters at thousands of env steps per second.  Joint limits are enforced by
    the servo command clip, joint speeds by scaling the step; a null-space term
    pulls the elbow towards the home posture.
    """

    def __init__(self, model: mujoco.MjModel, data: mujoco.MjData, limits: ControllerLimits | None = None) -> None:
        from panda_grasp_env.model.robot import PandaRobot, fast_index

        self.model, self.data = model, data
        self.robot = PandaRobot(model, data)
        self.limits = limits or ControllerLimits()
        self._columns, self._arm_qpos = fast_index(self.robot.arm_qvel_idx), fast_index(self.robot.arm_qpos_idx)
        self._jacp = np.zeros((3, model.nv))
        self._jacr = np.zeros((3, model.nv))
        self._jacobian = np.zeros((6, len(self.robot.arm_qvel_idx)))
        self._normal = np.zeros((6, 6))  # J J^T + damping^2 I, then its Cholesky factor
        self._rhs, self._solution = np.zeros(6), np.zeros(6)
        self._max_speed = np.asarray(self.limits.joint_speed)
        self._target_yaw, self._target_rotation = math.nan, np.eye(3)
        #: Where ``step`` servos the grasp site to: world metres, and the closing axis's heading, radians.
        self.goal_position, self.goal_yaw = np.zeros(3), 0.0

    def set_goal(self, position: np.ndarray, yaw: float) -> None:
        """Servo the grasp site towards ``position`` (world, metres), pointing down at ``yaw`` (radians)."""
        self.goal_position, self.goal_yaw = position, yaw

    def step(self, dt: float) -> np.ndarray:
        """Arm joint targets (7,) one servo step towards the goal (``command``)."""
        return self.command(self.goal_position, self.goal_yaw, dt)

    def command(
        self, position: np.ndarray, yaw: float, dt: float, damping: float = 0.05, posture_gain: float = 0.1
    ) -> np.ndarray:
        """Arm joint targets (7,) that move the grasp site towards ``position`` (world, metres), pointing down at ``yaw``.

        The damped least-squares step with a null-space posture term, ``J+ e + (I - J+ J) p`` with
        ``J+ = J^T (J J^T + damping^2 I)^-1``, is computed as ``p + J^T (J J^T + damping^2 I)^-1 (e - J p)``:
        one 6x6 Cholesky solve (MuJoCo's own, without numpy's per-call LAPACK overhead)."""
        site = self.robot.site_id
        mujoco.mj_jacSite(self.model, self.data, self._jacp, self._jacr, site)
        jacobian = self._jacobian
        jacobian[:3], jacobian[3:] = self._jacp[:, self._columns], self._jacr[:, self._columns]
        if yaw != self._target_yaw:
            self._target_yaw, self._target_rotation = yaw, top_down_rotation(yaw)
        # Orientation error: half the sum over the three axes of (current axis x target axis), which is
        # the vee of the skew-symmetric part of target @ current^T.
        mixed = self._target_rotation @ self.data.site_xmat[site].reshape(3, 3).T
        rhs = self._rhs
        rhs[:3] = position - self.data.site_xpos[site]
        rhs[3] = 0.5 * (mixed[2, 1] - mixed[1, 2])
        rhs[4] = 0.5 * (mixed[0, 2] - mixed[2, 0])
        rhs[5] = 0.5 * (mixed[1, 0] - mixed[0, 1])
        q = self.data.qpos[self._arm_qpos]
        posture = posture_gain * (HOME_QPOS - q)
        rhs -= jacobian @ posture
        normal = self._normal
        np.matmul(jacobian, jacobian.T, out=normal)
        normal.flat[::7] += damping**2
        mujoco.mju_cholFactor(normal, 0.0)
        mujoco.mju_cholSolve(self._solution, normal, rhs)
        step = posture + jacobian.T @ self._solution
        largest = float((np.abs(step) / self._max_speed).max()) / dt
        if largest > 1.0:
            step /= largest
        return q + step
