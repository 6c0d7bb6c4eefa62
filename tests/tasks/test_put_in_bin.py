"""PutInBin: a task whose one file builds its scene (the bin), registers its id and judges the episode."""

import gymnasium as gym
import mujoco
import numpy as np
import pytest

from panda_grasp_env.agents.evaluation.benchmarks import BENCHMARKS, Benchmark
from panda_grasp_env.agents.evaluation.episodes import make_agent, play_episode
from panda_grasp_env.agents.evaluation.protocol import EpisodeSpec
from panda_grasp_env.control.planning import MotionPlanner
from panda_grasp_env.registration import ENV_IDS, TASKS
from panda_grasp_env.tasks.put_in_bin import FLOOR_THICKNESS, INNER_HALF_WIDTH, WALL_HEIGHT, PutInBin


def make(**options):
    return gym.make("panda_grasp_env:PandaPutInBin-v0", **options)


def bin_geoms(model: mujoco.MjModel) -> set[int]:
    return {g for g in range(model.ngeom) if model.body(model.geom_bodyid[g]).name == "bin"}


@pytest.mark.unit
def test_the_task_file_registers_the_task_and_its_id_and_evaluation_its_benchmark():
    assert TASKS["PutInBin"] is PutInBin
    assert ENV_IDS["PandaPutInBin-v0"] == ({"task": "PutInBin"}, 10)
    assert BENCHMARKS["PutInBin"] == Benchmark("PandaPutInBin-v0", quick_seeds=10, full_seeds=100)


@pytest.mark.unit
def test_the_bin_is_in_the_simulation_and_in_the_planners_model():
    env = make(bin_position=(0.55, -0.1))
    cell = env.unwrapped.cell
    geoms = bin_geoms(cell.model)
    assert len(geoms) == 5
    assert np.allclose(cell.data.xpos[cell.model.body("bin").id], [0.55, -0.1, 0.0])
    assert len(bin_geoms(MotionPlanner(cell.config).model)) == 5  # the planner plans around it
    # Transit heights clear its walls like any object; the rays that place objects see its floor.
    assert max(top for *_, top in cell.fixtures.tops) == pytest.approx(FLOOR_THICKNESS + WALL_HEIGHT)
    assert cell.surface_below(0.55, -0.1)[0] == pytest.approx(FLOOR_THICKNESS)
    env.close()


@pytest.mark.unit
def test_reset_names_a_target_observes_it_and_keeps_blocks_out_of_the_bin():
    env = make(n_blocks=4)
    targets = set()
    for seed in range(12):
        observation, info = env.reset(seed=seed)
        index = env.unwrapped.cell.block_names.index(info["target"])
        assert observation["command"].tolist() == np.eye(4)[index].tolist()
        assert not info["target_in_bin"] and info["others_in_bin"] == 0
        positions = env.unwrapped.cell.block_positions()
        assert np.all(np.max(np.abs(positions[:, :2] - info["bin_position"][:2]), axis=1) > INNER_HALF_WIDTH + 0.03)
        targets.add(info["target"])
    assert len(targets) > 1
    assert make(target="green").reset(seed=0)[1]["target"] == "block_green"


@pytest.mark.unit
def test_success_needs_the_target_alone_in_the_bin():
    env = make(n_blocks=2, target="red")
    env.reset(seed=0)
    cell, task = env.unwrapped.cell, env.unwrapped.task
    inside = np.array([*task.bin_position, FLOOR_THICKNESS + 0.025])
    cell.set_body_pose(cell.block_ids[0], inside)
    cell.settle(0.3)
    verdict = task.evaluate(cell, None)
    assert verdict.success and verdict.terminated and verdict.reward == 1.0
    cell.set_body_pose(cell.block_ids[1], inside + [0.0, 0.0, 0.06])  # a second block on top of it
    cell.settle(0.5)
    verdict = task.evaluate(cell, None)
    assert verdict.info["others_in_bin"] == 1 and not verdict.success


@pytest.mark.parametrize("agent, seed", [("oracle", 0), ("planned", 1)])
def test_the_baselines_put_the_target_in_the_bin_touching_nothing_else(agent, seed):
    spec = EpisodeSpec(agent, "PutInBin", seed)
    env = gym.make(
        "panda_grasp_env:PandaPutInBin-v0", obs_mode="rgbd", cameras=("overhead", "front"), image_size=(640, 480)
    )
    cell = env.unwrapped.cell
    geoms, robot = bin_geoms(cell.model), set(cell.robot.body_ids)
    robot_on_bin = []

    def watch(cell):
        for contact in cell.data.contact[: cell.data.ncon]:
            pair = {contact.geom1, contact.geom2}
            if pair & geoms and {int(cell.model.geom_bodyid[g]) for g in pair} & robot:
                robot_on_bin.append(cell.sim_time)

    cell.physics.add_observer(watch)
    result = play_episode(env, make_agent(spec, env), spec)["result"]
    assert result["success"] and result["actions"] == 2
    assert result["disturbed"] == 0 and result["transit_contacts"] == 0
    assert robot_on_bin == []
    env.close()


def test_random_actions_do_not_solve_it():
    env = make()
    successes = 0
    for seed in range(3):
        env.reset(seed=seed)
        env.action_space.seed(seed)
        while True:
            _, _, terminated, truncated, info = env.step(env.action_space.sample())
            if terminated or truncated:
                break
        successes += info["is_success"]
    assert successes == 0


@pytest.mark.unit
@pytest.mark.parametrize(
    "options, culprit",
    [
        ({"n_blocks": 5}, "n_blocks"),
        ({"target": "purple"}, "target"),
        ({"n_blocks": 2, "target": "blue"}, "target"),
        ({"bin_position": (0.9, 0.0)}, "bin_position"),
        ({"bin_position": "left"}, "bin_position"),
        ({"bin_position": (0.5, float("nan"))}, "bin_position"),
    ],
)
def test_bad_options_name_the_culprit(options, culprit):
    with pytest.raises(ValueError, match=culprit):
        make(**options)
