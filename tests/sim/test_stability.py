"""What-if runs: a piece set on a copy of the simulation stands or falls there, and the live one is untouched."""

import numpy as np
import pytest

from panda_grasp_env.model.scene import SceneConfig
from panda_grasp_env.model.structures import Piece, Structure, structure_scene
from panda_grasp_env.sim.stability import what_if
from panda_grasp_env.sim.workcell import Workcell


@pytest.fixture(scope="module")
def cell():
    two = Structure("two", (Piece("cube", (0.0, 0.0, 0.025)), Piece("cube", (0.0, 0.0, 0.075))))
    cell = Workcell(structure_scene(SceneConfig(), two))
    cell.set_body_pose(int(cell.object_ids[0]), np.array([0.5, 0.0, 0.025]))
    cell.set_body_pose(int(cell.object_ids[1]), np.array([0.4, -0.2, 0.025]))
    cell.settle(0.5)
    return cell


@pytest.mark.parametrize(("offset", "stands"), [(0.0, True), (0.01, True), (0.035, False)])
def test_a_cube_set_on_another_stands_unless_its_centre_overhangs(cell, offset, stands):
    base, top = (int(b) for b in cell.object_ids[:2])
    before = cell.data.qpos.copy()
    result = what_if(cell.model, cell.data, {top: (np.array([0.5 + offset, 0.0, 0.075]), 0.0)}, [base, top])
    assert result.stands == stands, result
    np.testing.assert_array_equal(cell.data.qpos, before)  # the live simulation did not move


def test_a_body_without_a_free_joint_is_refused(cell):
    with pytest.raises(ValueError, match="free joint"):
        what_if(cell.model, cell.data, {0: (np.zeros(3), 0.0)}, [])
