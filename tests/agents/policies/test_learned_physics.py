"""The learned stability check: what_if's signature, the live simulation untouched, its inputs refused where
wrong, and the planner that asks it instead of the simulator."""

import copy

import gymnasium as gym
import mujoco
import numpy as np
import pytest

from panda_grasp_env.agents.evaluation.benchmarks import STRUCTURE_OPTIONS
from panda_grasp_env.agents.evaluation.protocol import skip_reason
from panda_grasp_env.agents.policies.learned_physics import FallModelCheck, Prediction, learned_lookahead_planner
from panda_grasp_env.agents.policies.registry import NAMED_AGENTS
from panda_grasp_env.sim.stability import set_free_pose

pytest.importorskip("torch")


@pytest.fixture(scope="module")
def check() -> FallModelCheck:
    return FallModelCheck()


def test_a_prediction_stands_below_its_threshold():
    assert Prediction(0.003, 0.004, 0.88).stands and not Prediction(0.004, 0.004, 0.88).stands


@pytest.mark.parametrize("threshold", [0.0, -1.0, float("nan"), "0.01"])
def test_a_threshold_that_is_no_positive_number_is_refused(threshold):
    with pytest.raises(ValueError, match="threshold"):
        FallModelCheck(threshold=threshold)


def test_a_fall_model_without_a_track_head_is_refused():
    with pytest.raises(ValueError, match="track head"):
        FallModelCheck("fall_convlstm")


def test_the_default_model_says_a_cube_on_the_table_stands_and_one_in_the_air_falls(check):
    """The structure-fall model, asked about a lone cube: set on the table it stands; 10 cm above it, over
    nothing, it falls (the tall-tower model called the first "falls": 18.5 mm)."""
    env = gym.make("panda_grasp_env:PandaStructure-v0", structure="bridge", **STRUCTURE_OPTIONS)
    env.reset(seed=0)
    cell = env.unwrapped.cell
    cube = int(cell.object_ids[0])
    on_table, in_air = (
        check(cell.model, cell.data, {cube: (np.array([0.5, 0.1, z]), 0.0)}, [cube]) for z in (0.025, 0.125)
    )
    assert on_table.stands and not in_air.stands
    env.close()


def test_the_check_reads_a_rendered_copy_and_leaves_the_simulation_as_it_was(check):
    env = gym.make("panda_grasp_env:PandaStructure-v0", structure="bridge", **STRUCTURE_OPTIONS)
    env.reset(seed=0)
    cell = env.unwrapped.cell
    before = cell.data.qpos.copy()
    cube, plank = cell.object_ids[0], cell.object_ids[-1]
    target = np.array([0.5, 0.1, 0.025])
    prediction = check(cell.model, cell.data, {int(cube): (target, 0.0)}, [int(plank)])
    np.testing.assert_array_equal(cell.data.qpos, before)
    # The default model answers with its settle head: how far a piece goes over 14 frames of 0.08 s.
    assert np.isfinite(prediction.shift) and prediction.shift >= 0 and prediction.seconds == pytest.approx(1.12)
    trial = copy.copy(cell.data)
    set_free_pose(cell.model, trial, int(cube), target, 0.0)
    mujoco.mj_forward(cell.model, trial)
    labels, depth, metres_per_pixel = check.frame(cell.model, trial, target, [int(cube)])
    assert labels.shape == depth.shape == (96, 96) and 0.003 < metres_per_pixel < 0.008
    rows, cols = np.nonzero(labels == 1)  # the cube, 5 cm across, in the middle of the crop
    assert abs(rows.mean() - 47.5) < 2 and abs(cols.mean() - 47.5) < 2
    assert rows.size * metres_per_pixel**2 == pytest.approx(0.05**2, rel=0.3)
    env.close()


def test_the_learned_planner_asks_the_fall_model_for_every_place(monkeypatch):
    asked = []
    monkeypatch.setattr(FallModelCheck, "__call__", lambda self, *args: asked.append(args) or Prediction(0, 1, 1))
    env = gym.make("panda_grasp_env:PandaStructure-v0", structure="seesaw", **STRUCTURE_OPTIONS)
    planner = learned_lookahead_planner(env, 0)
    observation, info = env.reset(seed=0)
    planner.reset(observation, info)
    for _ in range(4):
        observation, _, terminated, truncated, info = env.step(planner.act(observation, info))
    assert len(asked) >= 2 and info["primitive"] == "place" and info["primitive_success"]
    env.close()


def test_without_the_learn_extra_the_learned_planner_is_skipped_naming_it(monkeypatch):
    import panda_grasp_env.agents.evaluation.protocol as protocol

    assert NAMED_AGENTS["planned_lookahead_learned"].needs_learning_stack
    monkeypatch.setattr(protocol, "learning_stack_problem", lambda what: f"{what} needs the learn extra")
    assert (
        skip_reason("planned_lookahead_learned", "Structures4")
        == "agent planned_lookahead_learned needs the learn extra"
    )
    assert skip_reason("planned_lookahead", "Structures4") is None
