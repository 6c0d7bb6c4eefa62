"""StructureBuild: a target structure built, or pieces taken off one, judged with identical pieces matched
optimally; random actions build nothing."""

import mujoco
import numpy as np
import pytest

from panda_grasp_env.agents.policies.structure_builder import build_structure
from panda_grasp_env.env import PandaEnv
from panda_grasp_env.model.structures import Piece
from panda_grasp_env.primitives.result import PrimitiveResult
from panda_grasp_env.tasks.structure_build import GOAL_FIELDS, StructureBuild, is_away

PLACED = PrimitiveResult("place", True, "ok")


@pytest.mark.unit
@pytest.mark.parametrize(
    ("options", "culprit"),
    [
        ({"structure": "tower_99"}, "structure"),
        ({"structure": {"name": "x"}}, "structure"),
        ({"max_pieces": 1}, "max_pieces"),
        ({"structure": "ring_8", "max_pieces": 6}, "max_pieces"),
        ({"tiers": 5}, "tiers"),
        ({"tiers": []}, "tiers"),
        ({"structure": "bridge", "tiers": [2]}, "tiers"),
    ],
)
def test_bad_options_name_the_culprit(options, culprit):
    with pytest.raises(ValueError, match=culprit):
        StructureBuild(**options)


def test_random_structures_come_from_the_tiers_asked_for_within_the_budget():
    env = PandaEnv(task="StructureBuild", tiers=[4], max_pieces=5, obs_mode="state")
    names = set()
    for seed in range(3):
        _, info = env.reset(seed=seed)
        assert env.task.structure.tier == 4 and len(env.task.structure.kinds) <= 5
        names.add(info["structure"])
    assert names <= {"random_stair", "random_tee", "random_seesaw"}
    env.close()


@pytest.mark.parametrize(("structure", "seed"), [("bridge", 3), ("random", 4), ("pyramid_top", 3)])
def test_the_certificate_builds_what_the_task_calls_a_success(structure, seed):
    env = PandaEnv(task="StructureBuild", structure=structure)
    env.reset(seed=seed)
    task = env.task
    before = task.evaluate(env.cell, PLACED)
    assert not before.success
    slots = env.cell.object_ids[: len(task.structure.pieces)]
    assert build_structure(env.cell, task.structure, task.layout, slots).success
    after = task.evaluate(env.cell, PLACED)
    assert after.success and after.terminated and after.info["placed_fraction"] == 1.0 and after.info["away"]
    observation = env._observe()
    assert after.reward == env.compute_reward(observation["achieved_goal"], observation["desired_goal"], {}) == 0.0
    env.close()


def test_goals_are_observed_in_the_primitive_mode_and_relabel_as_hindsight_needs():
    env = PandaEnv(task="StructureBuild", structure="bridge", obs_mode="state")
    observation, info = env.reset(seed=0)
    assert set(observation) == {"observation", "achieved_goal", "desired_goal"}
    assert env.observation_space.contains(observation)
    desired = observation["desired_goal"].reshape(-1, GOAL_FIELDS)
    np.testing.assert_allclose(desired[:, :3], info["targets"], atol=1e-6)
    assert list(desired[:, 6]) == [1, 1, 2]  # cube, cube, plank
    achieved = observation["achieved_goal"]
    assert env.compute_reward(achieved, observation["desired_goal"], {}) == -1.0  # nothing built yet
    # Hindsight: what was achieved, taken as the goal, is reached; batches keep their shape.
    batch = np.stack([achieved, observation["desired_goal"]])
    np.testing.assert_array_equal(env.compute_reward(batch, batch[[0, 0]], {}), [0.0, -1.0])
    # One cube on a target: a third of the goal.
    one = achieved.reshape(-1, GOAL_FIELDS).copy()
    one[0, :5] = desired[1, :5]
    assert env.compute_reward(one.ravel(), observation["desired_goal"], {}) == pytest.approx(-2 / 3)
    one[0, 5] = 0.5  # tilted 29 degrees: not in place
    assert env.compute_reward(one.ravel(), observation["desired_goal"], {}) == -1.0
    env.close()


def _rolled(about_x: float, about_y: float, yaw: float) -> np.ndarray:
    """The (w, x, y, z) quaternion of a body rolled about its x axis, then its y axis (degrees), then turned
    ``yaw`` radians about world z."""
    roll, turn, quaternion = np.zeros(4), np.zeros(4), np.zeros(4)
    mujoco.mju_euler2Quat(roll, np.deg2rad([about_x, about_y, 0.0]), "XYZ")
    mujoco.mju_euler2Quat(turn, [0.0, 0.0, yaw], "xyz")
    mujoco.mju_mulQuat(quaternion, turn, roll)
    return quaternion


def test_a_piece_resting_on_a_face_like_its_bottom_stands_in_its_target():
    """A cube looks the same on any face and a plank on any long one: rolled so, each still fills its target;
    a plank stood on its end does not."""
    env = PandaEnv(task="StructureBuild", structure="bridge", obs_mode="state")
    env.reset(seed=0)
    task, model, data = env.task, env.cell.model, env.cell.data
    assert task.structure.kinds == ("cube", "cube", "plank")
    slots = env.cell.object_ids[: len(task.structure.pieces)]
    addresses = [model.jnt_qposadr[model.body_jntadr[body]] for body in slots]

    def put(rolls: list[tuple[float, float]]) -> int:
        for address, target, yaw, (about_x, about_y) in zip(addresses, task._targets, task._target_yaws, rolls):
            data.qpos[address : address + 3], data.qpos[address + 3 : address + 7] = (
                target,
                _rolled(about_x, about_y, yaw),
            )
        mujoco.mj_forward(model, data)
        return task.in_place(env.cell)

    assert put([(0.0, 0.0), (0.0, 0.0), (0.0, 0.0)]) == 3
    assert put([(0.0, 90.0), (90.0, 0.0), (180.0, 0.0)]) == 3  # cubes on their sides, the plank upside down
    assert put([(0.0, 90.0), (90.0, 0.0), (90.0, 0.0)]) == 3  # the plank on a long side
    assert put([(0.0, 30.0), (0.0, 0.0), (0.0, 0.0)]) == 2  # a cube leaning on an edge
    assert put([(0.0, 0.0), (0.0, 0.0), (0.0, 90.0)]) == 2  # the plank on its end
    env.close()


def test_pixel_observations_draw_the_goal_and_dense_rewards_measure_distance():
    env = PandaEnv(
        task="StructureBuild", structure="portal", obs_mode="heightmap", action_mode="pixel", reward_type="dense"
    )
    observation, _ = env.reset(seed=1)
    goal = observation["goal_heightmap"][..., 0]
    assert env.observation_space.contains(observation)
    assert goal.max() == pytest.approx(0.15, abs=1e-6)  # the lintel's top: two cubes and a plank
    # Four 5 cm pillars' and a 14 x 5 cm lintel's footprint, in 2 mm cells (the lintel covers the pillars' tops).
    assert abs((goal > 0).sum() * 0.002**2 - 0.14 * 0.05) < 0.0015
    reward = env.compute_reward(observation["achieved_goal"], observation["desired_goal"], {})
    assert -1.0 < reward < -0.05  # metres from the loose pieces to their targets
    env.close()


@pytest.mark.unit
def test_an_episode_may_build_another_structure_that_fits_the_slots():
    env = PandaEnv(task="StructureBuild", max_pieces=7, obs_mode="state")
    _, info = env.reset(seed=0, options={"structure": "table"})
    assert info["structure"] == "table" and info["n_targets"] == 7
    _, info = env.reset(seed=0)
    assert info["structure"].startswith("random_")
    for bad, culprit in ((("ring_8"), "8 pieces"), ("tower_99", "structure")):
        with pytest.raises(ValueError, match=culprit):
            env.reset(seed=0, options={"structure": bad})
    env.close()


def test_identical_pieces_count_in_any_target_of_their_kind():
    env = PandaEnv(task="StructureBuild", structure="row_3")
    env.reset(seed=0)
    task, cell = env.task, env.cell
    # The row's cubes stood in reverse order: every target holds a cube, so all three are in place.
    from panda_grasp_env.sim.structure_layout import stand_pieces

    pieces = list(reversed(task.structure.pieces))
    stand_pieces(cell, task.structure, pieces, cell.object_ids[:3], task.layout.origin, task.layout.heading)
    assert task.in_place(cell) == 3
    env.close()


def test_random_actions_build_nothing():
    env = PandaEnv(task="StructureBuild", structure="random")
    for seed in range(3):
        env.reset(seed=seed)
        env.action_space.seed(seed)
        for _ in range(8):
            _, _, terminated, _, info = env.step(env.action_space.sample())
            if terminated:
                break
        assert not info["is_success"]
    env.close()


@pytest.mark.unit
def test_a_prop_under_a_planks_end_is_in_the_goals_way_though_its_centre_lies_far_off():
    plank = Piece("plank", (0.5, 0.0, 0.075))
    prop = np.array([0.5 + 0.07 + 0.04 - 0.015, 0.0])  # 9.5 cm from the plank's centre, 1.5 cm under it
    assert not is_away(prop, [plank])
    assert is_away(prop + [0.0, 0.09], [plank])  # slid out sideways
