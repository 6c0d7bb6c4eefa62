import mujoco
import numpy as np
import pytest

from panda_grasp_env.model.robot import (
    FINGER_CLOSED,
    FINGER_HALF_THICKNESS,
    FINGER_HALF_WIDTH,
    FINGER_OPEN,
    FINGER_TIP_HALF_WIDTH,
    FINGERTIP_DEPTH,
    HAND_BODY_ABOVE_SITE,
    HAND_BODY_HALF_LENGTH,
    HAND_BODY_HALF_WIDTH,
    HOME_POSITION,
    HOME_YAW,
    fast_index,
)
from panda_grasp_env.model.scene import FINGER_BODIES, MAX_FINGER_GAP, SceneConfig
from panda_grasp_env.sim.workcell import Workcell


@pytest.mark.unit
def test_home_pose_points_down_above_the_workspace(cell, rng):
    cell.reset(rng)
    np.testing.assert_allclose(cell.robot.ee_position, HOME_POSITION, atol=2e-3)
    assert cell.robot.ee_rotation[:, 2] == pytest.approx([0, 0, -1], abs=1e-2)
    assert np.cos(cell.robot.ee_yaw - HOME_YAW) ** 2 == pytest.approx(1.0, abs=1e-3)
    assert cell.robot.finger_gap == pytest.approx(MAX_FINGER_GAP, abs=1e-3)


@pytest.mark.unit
def test_gripper_closes_and_opens(cell, rng):
    cell.reset(rng)
    cell.actuate_gripper(close=True)
    assert cell.robot.finger_gap < 1e-3
    cell.actuate_gripper(close=False)
    assert cell.robot.finger_gap > MAX_FINGER_GAP - 2e-3


@pytest.mark.unit
def test_an_opening_finger_stops_at_its_stop(rng, soften_finger_limits):
    # The fingers are light, so a soft joint limit let them fly 9.6 mm past it (finger_gap clips this).
    widest = {}
    for limits in ("soft", "as built"):
        cell = Workcell()
        if limits == "soft":
            soften_finger_limits(cell.model)
        cell.reset(rng)
        cell.actuate_gripper(close=True)
        cell.robot.open_gripper()
        widest[limits] = 0.0
        for _ in range(10 * cell.physics.control_substeps):  # every physics step, so the peak is seen
            mujoco.mj_step(cell.model, cell.data)
            widest[limits] = max(widest[limits], float(cell.data.qpos[cell.robot.finger_qpos_idx].max()))
    assert widest["soft"] > FINGER_OPEN + 5e-3  # 9.6 mm: the stop met at 1.75 m/s
    assert FINGER_OPEN - 1e-3 < widest["as built"] < FINGER_OPEN + 2.5e-3  # 1.5 mm, for a moment


@pytest.mark.unit
def test_a_block_held_above_the_pads_counts_as_held(rng):
    # A block that rode up past the pads is held by the fingers behind them; a pads-only test called such
    # grasps dropped, and the arm then let go of objects it had carried home, outside the workspace.
    cell = Workcell(SceneConfig(block_size=0.03))
    cell.reset(rng)
    site = np.array([0.5, 0.0, 0.2])
    cell.motion.teleport_hand(site, HOME_YAW)
    block = int(cell.block_ids[0])
    cell.set_body_pose(block, site + [0.0, 0.0, 0.03])  # its bottom 1.5 cm above the pads' centre
    cell.actuate_gripper(close=True)
    assert not pad_contacts(cell, block)
    start = cell.data.xpos[block][2]
    cell.motion.move_to(site + [0.0, 0.0, 0.1], HOME_YAW)
    cell.wait(0.5)
    assert cell.data.xpos[block][2] - start > 0.09 and not pad_contacts(cell, block)
    assert cell.robot.body_between_fingers() == block


@pytest.mark.unit
def test_the_table_under_both_fingertips_is_not_held(rng):
    cell = Workcell()
    cell.reset(rng)
    cell.actuate_gripper(close=True)
    cell.motion.move_to(np.array([0.3, 0.3, 0.005]), HOME_YAW, settle_timeout=0.3)  # fingertips pressed on the table
    # Both rest on it (within the contacts' 1 mm margin; stiff contacts may leave one just outside it).
    table = cell.model.geom("table").id
    for finger in cell.robot.finger_bodies:
        first = cell.model.body_geomadr[finger]
        gaps = [
            mujoco.mj_geomDistance(cell.model, cell.data, geom, table, 0.01, None)
            for geom in range(first, first + cell.model.body_geomnum[finger])
            if cell.model.geom_contype[geom]
        ]
        assert min(gaps) < 0.002
    assert set(cell.robot.finger_bodies) & cell.bodies_touching(0) and cell.robot.body_between_fingers() is None


def pad_contacts(cell: Workcell, body: int) -> set[int]:
    """The finger pads touching ``body``."""
    pads = {cell.model.geom(f"{finger}_pad").id for finger in FINGER_BODIES}
    return {
        geom
        for c in cell.data.contact[: cell.data.ncon]
        for geom, other in ((c.geom1, c.geom2), (c.geom2, c.geom1))
        if geom in pads and cell.model.geom_bodyid[other] == body
    }


@pytest.mark.unit
@pytest.mark.parametrize("target, yaw", [((0.5, 0.2, 0.15), 0.3), ((0.65, -0.25, 0.05), -1.2), ((0.3, 0.0, 0.3), 1.5)])
def test_cartesian_controller_reaches_targets_within_joint_limits(cell, rng, target, yaw):
    cell.reset(rng)
    outcome = cell.motion.move_to(np.array(target), yaw)
    assert outcome.reached and outcome.error < 4e-3
    # Parallel gripper: heading is defined modulo a half turn.
    assert np.sin(cell.robot.ee_yaw - yaw) == pytest.approx(0.0, abs=0.02)
    q = cell.robot.joint_positions
    assert np.all(q >= cell.robot.arm_lower - 1e-3) and np.all(q <= cell.robot.arm_upper + 1e-3)


@pytest.mark.unit
def test_reference_speed_is_bounded(cell, rng):
    cell.reset(rng)
    positions = []

    def watch(cell):
        positions.append(cell.robot.ee_position)

    cell.physics.add_observer(watch)
    try:
        cell.motion.move_to(np.array([0.6, 0.2, 0.2]), HOME_YAW)
    finally:
        cell.physics.remove_observer(watch)
    speeds = np.linalg.norm(np.diff(positions, axis=0), axis=1) / cell.physics.control_dt
    assert speeds.max() < cell.controller.limits.linear_speed * 1.5


def test_ik_keeps_up_with_large_combined_moves(cell):
    """Regression: a 30 cm carry with a 78 degree turn once outran a 1.5 rad/s joint cap and sagged 12 cm."""
    from panda_grasp_env.agents.policies.towers import build_tower, on_workcell

    errors = []

    def watch(cell):
        errors.append(cell.controller.tracking_error())

    cell.physics.add_observer(watch)
    try:
        cell.reset(np.random.default_rng(59), "scattered")
        assert build_tower(cell, on_workcell(cell)).success
    finally:
        cell.physics.remove_observer(watch)
    assert max(errors) < 0.005


@pytest.mark.unit
def test_fast_index_is_a_slice_only_for_consecutive_indices():
    values = np.arange(20.0)
    assert fast_index(np.array([3, 4, 5])) == slice(3, 6)
    assert np.array_equal(values[fast_index(np.array([3, 4, 5]))], values[[3, 4, 5]])
    for indices in (np.array([3, 5, 6]), np.array([5, 4]), np.array([], dtype=int)):
        assert fast_index(indices) is indices


def reach(model, data, geom: int, direction: np.ndarray) -> float:
    """How far (metres) collision geom ``geom`` reaches along unit ``direction`` (world): its support."""
    centre, rotation, size = data.geom_xpos[geom], data.geom_xmat[geom].reshape(3, 3), model.geom_size[geom]
    kind = model.geom_type[geom]
    if kind == mujoco.mjtGeom.mjGEOM_MESH:
        mesh = model.geom_dataid[geom]
        start = model.mesh_vertadr[mesh]
        vertices = model.mesh_vert[start : start + model.mesh_vertnum[mesh]] @ rotation.T + centre
        return float((vertices @ direction).max())
    if kind == mujoco.mjtGeom.mjGEOM_BOX:
        return float(centre @ direction + np.abs(rotation.T @ direction) @ size)
    if kind == mujoco.mjtGeom.mjGEOM_CAPSULE:
        return float(centre @ direction + abs(rotation[:, 2] @ direction) * size[1] + size[0])
    assert kind == mujoco.mjtGeom.mjGEOM_SPHERE, kind
    return float(centre @ direction + size[0])


@pytest.mark.unit
def test_the_hand_constants_match_the_models_collision_geometry():
    """``model.robot``'s closed-hand sizes, measured on the collision geoms of the closed fingers and of the
    hand body, from the grasp site: what the scaffold slide-out's clearances rest on."""
    cell = Workcell(SceneConfig())
    cell.robot.teleport_fingers(FINGER_CLOSED)
    mujoco.mj_forward(cell.model, cell.data)
    model, data = cell.model, cell.data
    site, yaw = cell.robot.ee_position, cell.robot.ee_yaw
    closing, across, up = (
        np.array([np.cos(yaw), np.sin(yaw), 0.0]),
        np.array([-np.sin(yaw), np.cos(yaw), 0.0]),
        np.eye(3)[2],
    )
    fingers, body = [], []
    for geom in range(model.ngeom):
        name = mujoco.mj_id2name(model, mujoco.mjtObj.mjOBJ_BODY, int(model.geom_bodyid[geom])) or ""
        if model.geom_contype[geom] or model.geom_conaffinity[geom]:
            (fingers if "finger" in name else body if name.endswith(("link7", "hand")) else []).append(geom)

    def extent(geoms, direction):
        return max(reach(model, data, g, direction) for g in geoms) - site @ direction

    assert -extent(fingers, -up) == pytest.approx(-FINGERTIP_DEPTH, abs=0.001)
    assert max(extent(fingers, closing), extent(fingers, -closing)) == pytest.approx(FINGER_HALF_WIDTH, abs=0.001)
    tips = [g for g in fingers if extent([g], up) < 0.0315 + 1e-4]  # the geoms of the fingers' lowest 3 cm
    assert max(extent(tips, closing), extent(tips, -closing)) <= FINGER_TIP_HALF_WIDTH + 1e-4
    below_base = [g for g in fingers if extent([g], up) < 0.056 + 1e-4]
    assert max(extent(below_base, across), extent(below_base, -across)) <= FINGER_HALF_THICKNESS + 1e-4
    assert -extent(body, -up) == pytest.approx(HAND_BODY_ABOVE_SITE, abs=0.001)
    assert max(extent(body, closing), extent(body, -closing)) <= HAND_BODY_HALF_LENGTH
    assert max(extent(body, across), extent(body, -across)) <= HAND_BODY_HALF_WIDTH
