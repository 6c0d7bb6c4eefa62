"""Fixtures with state: a task moves and resizes them per episode, and the robot's contacts with them count."""

import mujoco
import numpy as np
import pytest

from panda_grasp_env.control.planning import MotionPlanner
from panda_grasp_env.model.robot import HOME_QPOS
from panda_grasp_env.model.scene import SceneConfig
from panda_grasp_env.primitives.top_down import grasp, push
from panda_grasp_env.sim.workcell import Workcell


def box_fixture(body_name: str, geom_name: str, half_size: list[float]):
    """A fixture builder: one static body with one box geom at its origin."""

    def add(spec: mujoco.MjSpec) -> None:
        body = spec.worldbody.add_body()
        body.name = body_name
        geom = body.add_geom()
        geom.name, geom.type, geom.size = geom_name, mujoco.mjtGeom.mjGEOM_BOX, half_size

    return add


@pytest.fixture(scope="module")
def walled():
    """A workcell with one block and a 8 cm high wall (a body), moved by the tests."""
    return Workcell(SceneConfig(n_blocks=1, fixtures=box_fixture("wall", "wall_plate", [0.01, 0.1, 0.04])))


@pytest.mark.unit
def test_pushing_into_a_fixture_reports_collision_and_names_it(walled):
    walled.clear()
    walled.fixtures.set_pose("wall", [0.55, 0.0, 0.04])
    result = push(walled, 0.45, 0.0, 0.03, 0.0, 0.15)  # the stroke ends 5 cm inside the wall
    assert (result.success, result.reason) == (False, "collision")
    assert result.work_contacts == ["wall"] and result.transit_contacts == []
    # The stroke stopped at the touch: the hand did not drive on into the wall.
    assert walled.robot.ee_position[0] < 0.5


@pytest.mark.unit
def test_a_push_clear_of_a_moved_fixture_touches_nothing(walled):
    walled.clear()
    walled.fixtures.set_pose("wall", [0.45, 0.25, 0.04], yaw=np.pi / 2)  # along x, beside the stroke
    result = push(walled, 0.45, 0.0, 0.03, 0.0, 0.15)
    assert (result.reason, result.work_contacts, result.transit_contacts) == ("no_contact", [], [])


@pytest.mark.unit
def test_a_grasp_on_a_fixture_it_is_aimed_at_is_no_collision(walled):
    walled.clear()
    walled.fixtures.set_pose("wall", [0.5, 0.0, 0.04], yaw=np.pi / 2)  # lying across: 20 cm long, 2 cm deep
    block = int(walled.block_ids[0])
    walled.set_body_pose(block, np.array([0.5, 0.0, 0.08 + 0.025]))
    walled.settle(0.2)
    result = grasp(walled, 0.5, 0.0, 0.105, 0.0)  # fingers along x: they clear the 2 cm deep wall
    assert result.reason == "ok" and "wall" not in result.transit_contacts


@pytest.mark.unit
def test_fixture_poses_and_sizes_move_rays_heights_and_the_planners_model():
    cell = Workcell(SceneConfig(n_blocks=1, fixtures=box_fixture("crate", "crate_box", [0.05, 0.05, 0.05])))
    planner = MotionPlanner(cell.config)
    cell.clear()
    assert planner.is_valid(HOME_QPOS)
    hand = cell.robot.ee_position.copy()
    cell.fixtures.set_size("crate_box", [0.08, 0.08, 0.1])
    cell.fixtures.set_pose("crate", hand, yaw=0.3)  # around the hand at home
    assert cell.fixtures.below(*hand[:2]) == "crate"
    assert cell.surface_below(*hand[:2])[0] == pytest.approx(hand[2] + 0.1)
    assert cell.motion.tallest_top() == pytest.approx(hand[2] + 0.1)
    planner.sync_fixtures(cell.model)
    assert not planner.is_valid(HOME_QPOS)
    cell.fixtures.set_pose("crate", [0.5, -0.2, 0.1])
    planner.sync_fixtures(cell.model)
    assert planner.is_valid(HOME_QPOS)
    assert cell.fixtures.below(0.5, -0.2) == "crate" and cell.fixtures.below(0.5, 0.2) is None


@pytest.mark.unit
def test_a_resized_fixture_holds_a_block_where_only_its_new_size_reaches():
    cell = Workcell(SceneConfig(n_blocks=1, fixtures=box_fixture("crate", "crate_box", [0.03, 0.03, 0.03])))
    cell.clear()
    cell.fixtures.set_size("crate_box", [0.12, 0.12, 0.03])
    cell.fixtures.set_pose("crate", [0.5, 0.0, 0.03])
    block = int(cell.block_ids[0])
    cell.set_body_pose(block, np.array([0.59, 0.0, 0.12]))  # over the grown top, 9 cm from its centre
    cell.wait(1.0)
    assert cell.data.xpos[block][2] == pytest.approx(0.06 + 0.025, abs=0.003)


@pytest.mark.unit
@pytest.mark.parametrize(
    "call,culprit",
    [
        (lambda c: c.fixtures.set_pose("table", [0.5, 0.0, 0.0]), "table"),
        (lambda c: c.fixtures.set_pose("wall", [0.5, np.nan, 0.0]), "wall"),
        (lambda c: c.fixtures.set_size("wall_plate", [0.1, 0.1]), "wall_plate"),
        (lambda c: c.fixtures.set_size("floor", [1.0, 1.0, 1.0]), "floor"),
    ],
)
def test_bad_fixture_changes_name_the_culprit(walled, call, culprit):
    with pytest.raises(ValueError, match=culprit):
        call(walled)


def test_a_transit_over_a_fixture_that_moves_per_seed_touches_nothing_on_100_seeds():
    """Each seed puts a pillar of its own height and heading somewhere else; the hand crosses over it from one
    side to the other.  Transit clears the pillar where it stands now, and the pillar's
    contacts count: a stale height (the compiled 10 cm) would be touched by most seeds."""
    cell = Workcell(SceneConfig(n_blocks=1, fixtures=box_fixture("pillar", "pillar_box", [0.03, 0.05, 0.05])))
    touched = {}
    for seed in range(100):
        rng = np.random.default_rng(seed)
        cell.clear()
        height = rng.uniform(0.1, 0.3)
        cell.fixtures.set_size("pillar_box", [0.03, 0.05, height / 2])
        x, y = rng.uniform(0.4, 0.6), rng.uniform(-0.1, 0.1)
        cell.fixtures.set_pose("pillar", [x, y, height / 2], rng.uniform(-np.pi, np.pi))
        cell.collateral.begin()
        cell.motion.transit(x - 0.15, y - 0.2, 0.0)
        cell.motion.transit(x + 0.1, y + 0.2, 0.0)  # the straight line passes within 4 cm of the pillar's axis
        record = cell.collateral.finish(set())
        if record.transit_fixtures:
            touched[seed] = record.transit_fixtures
    assert touched == {}
