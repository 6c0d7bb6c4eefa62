"""Cartesian controller: drives the grasp site to a target pose at bounded speed.

Choice: differential inverse kinematics with ``mink`` on a robot-only model
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

from dataclasses import dataclass

import mink
import numpy as np

from panda_grasp_env.robot import HOME_QPOS, top_down_rotation
from panda_grasp_env.scene import ARM_JOINTS, GRASP_SITE, SceneConfig, build_spec


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
        self.goal_speed = self.limits.linear_speed

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

    def set_goal(self, position: np.ndarray, yaw: float, speed: float | None = None) -> None:
        """New goal: grasp site at ``position`` (world, metres), pointing down, closing axis at ``yaw``.

        The reference travels there at ``speed`` m/s (default and cap: ``limits.linear_speed``).
        A parallel gripper is symmetric under a half turn, so ``yaw`` is wrapped
        into the half-turn window that keeps joint 7 near the middle of its range.
        """
        self.goal_position = np.asarray(position, dtype=float).copy()
        self.goal_yaw = wrap_gripper_yaw(yaw, self.goal_position)
        self.goal_speed = self.limits.linear_speed if speed is None else min(speed, self.limits.linear_speed)

    def stop(self) -> None:
        """Make the current reference the goal: the hand stays where it is commanded now."""
        self.goal_position = self.reference_position.copy()
        self.goal_yaw = self.reference_yaw

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
        distance = np.linalg.norm(offset)
        max_step = self.goal_speed * dt
        if distance > max_step:
            offset *= max_step / distance
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
        return self.commanded_qpos

    def tracking_error(self) -> float:
        """Position error of the IK's own solution against its reference, metres."""
        pose = self.configuration.get_transform_frame_to_world(GRASP_SITE, "site")
        return float(np.linalg.norm(pose.translation() - self.reference_position))
