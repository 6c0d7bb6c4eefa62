"""Pose IK and the tolerance sampler."""

import numpy as np
import pytest

from panda_grasp_env.control.ik import PoseIK, ToleranceSampler
from panda_grasp_env.geometry import rotation_about, top_down_rotation
from panda_grasp_env.model.robot import HOME_QPOS

pytestmark = pytest.mark.unit  # every test here is fast: the unit tier (python -m pytest -m unit)


@pytest.fixture(scope="module")
def ik():
    return PoseIK()


def test_ik_reaches_a_top_down_pose_within_tolerance(ik):
    import mujoco

    position, rotation = np.array([0.5, 0.1, 0.1]), top_down_rotation(0.3)
    result = ik.solve(position, rotation, HOME_QPOS, np.random.default_rng(0))
    assert result is not None and result.position_error < 0.001 and result.angle_error < np.deg2rad(1)
    data = mujoco.MjData(ik.model)
    data.qpos[ik.arm] = result.qpos
    mujoco.mj_kinematics(ik.model, data)
    site = ik.model.site("grasp_site").id
    assert np.linalg.norm(data.site_xpos[site] - position) < 0.0015
    assert np.all(result.qpos >= ik.lower - 1e-6) and np.all(result.qpos <= ik.upper + 1e-6)


def test_unreachable_pose_returns_none(ik):
    assert ik.solve(np.array([1.5, 0.0, 0.1]), top_down_rotation(0.0), HOME_QPOS, np.random.default_rng(0)) is None


def test_tolerance_sampler_goes_from_the_middle_outward():
    rotation = top_down_rotation(0.0)
    orientations = list(ToleranceSampler().orientations(rotation))
    assert np.allclose(orientations[0], rotation)
    angles = [np.degrees(np.arccos(np.clip((np.trace(rotation.T @ o) - 1) / 2, -1, 1))) for o in orientations]
    assert max(angles) < 35 and angles[1] > 0
    assert all(np.allclose(o.T @ o, np.eye(3), atol=1e-9) for o in orientations)


def test_tolerance_sampler_rescues_a_pose_the_exact_orientation_cannot_reach(ik):
    # Approach 60 deg from vertical facing away from the robot, straight ahead: the wrist cannot hold it
    # exactly (found by benchmarks/ik_reachability.py), a few degrees off it can.
    rotation = rotation_about([0.0, 1.0, 0.0], -np.deg2rad(60)) @ top_down_rotation(np.pi / 2)
    position = np.array([0.5, 0.0, 0.05])
    assert ik.solve(position, rotation, HOME_QPOS, np.random.default_rng(0)) is None
    result, tried = ToleranceSampler().solve(ik, position, rotation, HOME_QPOS, np.random.default_rng(0))
    assert result is not None and tried > 1
    assert np.degrees(np.arccos(np.clip((np.trace(rotation.T @ result.rotation) - 1) / 2, -1, 1))) < 35


def test_planner_finds_a_collision_free_path_around_a_wall():
    from panda_grasp_env.control.planning import Box, MotionPlanner

    planner = MotionPlanner(obstacles=(Box((0.45, 0.0, 0.15), (0.01, 0.3, 0.15)),), seed=0)
    goal = PoseIK().solve(np.array([0.6, 0.1, 0.08]), top_down_rotation(0.0), HOME_QPOS, np.random.default_rng(0))
    result = planner.plan(HOME_QPOS, goal.qpos, time_limit=5.0)
    assert result.success and np.allclose(result.path[0], HOME_QPOS) and np.allclose(result.path[-1], goal.qpos)
    for a, b in zip(result.path, result.path[1:]):  # every segment, densely
        assert all(planner.is_valid(a + t * (b - a)) for t in np.linspace(0, 1, 50))
    assert result.length >= np.linalg.norm(goal.qpos - HOME_QPOS) - 1e-9


def test_planner_refuses_a_goal_in_collision_and_unknown_planners():
    from panda_grasp_env.control.planning import Box, MotionPlanner

    planner = MotionPlanner(obstacles=(Box((0.5, 0.0, 0.1), (0.3, 0.3, 0.1)),))
    goal = PoseIK().solve(np.array([0.5, 0.0, 0.1]), top_down_rotation(0.0), HOME_QPOS, np.random.default_rng(0))
    result = planner.plan(HOME_QPOS, goal.qpos, time_limit=0.5)
    assert not result.success and "goal in collision" in result.planner
    with pytest.raises(ValueError, match="RRTConnect"):
        MotionPlanner(planner="SBL-ish")


def test_servo_step_is_the_damped_least_squares_step_with_posture(cell, rng):
    """The servo's one-solve form equals J+ e + (I - J+ J) p with J+ = J^T (J J^T + d^2 I)^-1, written out."""
    import mujoco

    from panda_grasp_env.control.controller import JacobianServo

    servo = JacobianServo(cell.model, cell.data)
    robot, damping, gain, dt = cell.robot, 0.05, 0.1, 1.0  # dt large: no speed scaling, the raw step is compared
    for _ in range(20):
        cell.clear()
        cell.data.qpos[robot.arm_qpos_idx] = HOME_QPOS + rng.uniform(-0.4, 0.4, 7)
        mujoco.mj_forward(cell.model, cell.data)
        target, yaw = cell.data.site_xpos[robot.site_id] + rng.normal(0, 0.05, 3), rng.uniform(-np.pi, np.pi)
        jacp, jacr = np.zeros((3, cell.model.nv)), np.zeros((3, cell.model.nv))
        mujoco.mj_jacSite(cell.model, cell.data, jacp, jacr, robot.site_id)
        jacobian = np.vstack([jacp[:, robot.arm_qvel_idx], jacr[:, robot.arm_qvel_idx]])
        current, wanted = cell.data.site_xmat[robot.site_id].reshape(3, 3), top_down_rotation(yaw)
        turn = 0.5 * sum(np.cross(current[:, axis], wanted[:, axis]) for axis in range(3))
        error = np.concatenate([target - cell.data.site_xpos[robot.site_id], turn])
        pseudo_inverse = jacobian.T @ np.linalg.inv(jacobian @ jacobian.T + damping**2 * np.eye(6))
        q = cell.data.qpos[robot.arm_qpos_idx].copy()
        step = pseudo_inverse @ error + (np.eye(7) - pseudo_inverse @ jacobian) @ (gain * (HOME_QPOS - q))
        np.testing.assert_allclose(servo.command(target, yaw, dt, damping, gain), q + step, atol=1e-12)
