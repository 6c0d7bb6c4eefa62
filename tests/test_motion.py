"""Pose IK and the tolerance sampler."""

import numpy as np
import pytest

from panda_grasp_env.control.ik import PoseIK, ToleranceSampler
from panda_grasp_env.geometry import rotation_about, top_down_rotation
from panda_grasp_env.model.robot import HOME_QPOS


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
