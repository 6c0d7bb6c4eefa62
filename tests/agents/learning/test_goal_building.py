"""The goal-conditioned structure learner (``agents/learning/goal_building.py``): the outcome reward under any
goal, hindsight goals, the block-count curriculum, the goal plane the Q-network sees and its place mask."""

import gymnasium as gym
import numpy as np
import pytest
import torch as th

from panda_grasp_env.agents.learning.config import config_from_dict, load_config, training_env
from panda_grasp_env.agents.learning.goal_building import (
    BlockBudget,
    GoalHeightmapDQN,
    StructureOutcomeReward,
    draw_goal,
    hindsight_goal,
    open_kinds,
    structure_outcome,
)
from panda_grasp_env.agents.learning.heightmap_observations import (
    GOAL_HEIGHT_RANGE,
    encode_heightmap,
    encode_observation,
    held_kind,
    holding_level,
)
from panda_grasp_env.agents.learning.heightmap_policy import HeightmapQPolicy
from panda_grasp_env.perception.heightmap import HeightmapGrid
from panda_grasp_env.tasks.structure_build import GOAL_FIELDS, KIND_CODES, goal_rows

SLOTS = 6
#: A span: two cubes 9 cm apart and a plank across them.
SPAN = goal_rows(
    ["cube", "cube", "plank"],
    np.array([[0.45, -0.045, 0.025], [0.45, 0.045, 0.025], [0.45, 0.0, 0.075]]),
    np.array([0.0, 0.0, np.pi / 2]),
    np.zeros(3),
    SLOTS,
).ravel()
START = goal_rows(
    ["cube", "cube", "plank"],
    np.array([[0.35, -0.15, 0.025], [0.55, 0.15, 0.025], [0.35, 0.15, 0.025]]),
    np.array([0.3, 0.0, 0.1]),
    np.zeros(3),
    SLOTS,
).ravel()


def moved(goal: np.ndarray, slot: int, centre: list[float], yaw: float = 0.0) -> np.ndarray:
    """``goal`` with slot ``slot``'s piece at ``centre`` (world metres), upright, turned ``yaw``."""
    rows = goal.reshape(-1, GOAL_FIELDS).copy()
    turns = 2.0 if rows[slot, 6] == KIND_CODES["plank"] else 4.0
    rows[slot, :6] = [*centre, np.cos(turns * yaw), np.sin(turns * yaw), 0.0]
    return rows.ravel()


def pieces(goal: np.ndarray) -> np.ndarray:
    rows = goal.reshape(-1, GOAL_FIELDS)
    return rows[rows[:, 6] > 0]


@pytest.mark.unit
def test_each_primitive_is_paid_for_what_it_achieved_toward_the_goal():
    assert open_kinds(pieces(START), pieces(SPAN)) == {KIND_CODES["cube"]}  # the plank has nothing to rest on
    assert structure_outcome(START, START, SPAN, grasped=2) == 0.0  # the plank, too early
    assert structure_outcome(START, START, SPAN, grasped=0) == 1.0  # a cube: useful
    one = moved(START, 0, [0.45, -0.045, 0.025])
    assert structure_outcome(START, one, SPAN, grasped=None) == 1.0  # a target filled
    assert structure_outcome(one, one, SPAN, grasped=0) == 0.0  # grasping a piece in place pays nothing...
    assert structure_outcome(one, START, SPAN, grasped=None) == -1.0  # ...and losing it costs one
    two = moved(one, 1, [0.45, 0.045, 0.025])
    assert open_kinds(pieces(two), pieces(SPAN)) == {KIND_CODES["plank"]}
    assert structure_outcome(two, two, SPAN, grasped=2) == 1.0
    built = moved(two, 2, [0.45, 0.0, 0.075], np.pi / 2)
    assert structure_outcome(two, built, SPAN, grasped=None) == 2.0  # the last target, and the whole goal
    off = moved(two, 2, [0.45, 0.02, 0.075], np.pi / 2)  # 2 cm off: outside the 1 cm tolerance
    assert structure_outcome(two, off, SPAN, grasped=None) == 0.0


@pytest.mark.unit
def test_a_hindsight_goal_holds_the_upright_pieces_the_episode_moved_and_not_the_held_one():
    assert hindsight_goal(START, START, held=None) is None
    one = moved(START, 0, [0.45, -0.045, 0.025])
    goal = hindsight_goal(START, one, held=None)
    assert len(pieces(goal)) == 1 and np.allclose(pieces(goal)[0, :3], [0.45, -0.045, 0.025])
    assert hindsight_goal(START, one, held=0) is None
    tipped = one.reshape(-1, GOAL_FIELDS).copy()
    tipped[0, 5] = 1.2
    assert hindsight_goal(START, tipped.ravel(), held=None) is None
    # The step that achieved it is paid in full under it: the place fills the goal.
    assert structure_outcome(START, one, goal, grasped=None) == 2.0
    grid = HeightmapGrid(resolution=0.004)
    image = draw_goal(grid, goal)
    row, col = grid.cell_position(np.array([0.45, -0.045])).astype(int)
    assert image[row, col] == pytest.approx(0.05) and (image > 0).sum() == pytest.approx(13 * 13, abs=40)


@pytest.mark.unit
def test_the_goal_plane_and_the_held_kind_reach_the_policy():
    heightmap = np.zeros((40, 40, 4), dtype=np.float32)
    goal = np.zeros((40, 40, 1), dtype=np.float32)
    goal[20:25, 20:25] = 0.1
    encoded = encode_heightmap(heightmap, holding_level(True, KIND_CODES["plank"]), goal=goal)
    assert encoded.shape == (6, 40, 40) and encoded[4].min() == 213
    assert encoded[5, 22, 22] == round(0.1 / GOAL_HEIGHT_RANGE * 255) and encoded[5, 0, 0] == 0
    achieved = START.copy()
    info = {"primitive": "grasp", "primitive_success": True, "primitive_object": "object_2"}
    assert held_kind(achieved, info) == KIND_CODES["plank"]
    assert held_kind(achieved, {**info, "primitive_object": "object_5"}) is None  # an empty slot
    observation = {"heightmap": heightmap, "goal_heightmap": goal, "achieved_goal": achieved, "desired_goal": SPAN}
    assert encode_observation(observation, info, holding_plane=True)[4, 0, 0] == 213
    assert encode_observation(observation, {}, holding_plane=True)[4].max() == 0
    # Holding anything opens the place mask on the goal's footprint as well as on occupied cells.
    policy = HeightmapQPolicy(
        gym.spaces.Box(0, 255, (6, 40, 40), dtype=np.uint8),
        gym.spaces.Discrete(3 * 4 * 1600),
        lambda _: 1e-3,
        primitives=("grasp", "place", "push"),
        rotations=4,
        cell_size=0.01,
        primitives_used=("grasp", "place"),
        goal=True,
    )
    allowed = policy.q_net.allowed(th.as_tensor(encoded[None]))[0].reshape(3, 4, 40, 40)
    assert allowed[1, :, 20:25, 20:25].all() and allowed[1].sum() == 4 * 25 and not allowed[0].any()
    assert policy.q_net(th.as_tensor(encoded[None])).shape == (1, 3 * 4 * 1600)
    # The acting rules read heights on the goal policy's scale: a failed grasp's 5 mm is 2.5 levels, not 5.
    assert policy.failure_memory().tolerance == pytest.approx(0.005 / GOAL_HEIGHT_RANGE * 255)
    with pytest.raises(ValueError, match="planks"):
        policy.face_centring(0.05)


@pytest.fixture(scope="module")
def structure_config():
    return load_config(
        "configs/structure_builder_dqn.yaml",
        # The learner alone: the teacher has its own test.
        [
            "env_kwargs.rotations=4",
            "algo_kwargs.buffer_size=200",
            "algo_kwargs.learning_starts=4",
            "algo_kwargs.teacher_episodes=0",
        ],
    )


def test_the_training_env_draws_within_the_budget_and_pays_the_outcome(structure_config):
    env = training_env(structure_config)
    budget = env.get_wrapper_attr("set_block_budget")
    assert isinstance(env.env, StructureOutcomeReward) and isinstance(env.env.env, BlockBudget)
    with pytest.raises(ValueError, match="block budget"):
        budget(7)
    budget(2)
    counts = set()
    for seed in range(6):
        observation, info = env.reset(seed=seed)
        counts.add(info["n_targets"])
        assert observation.shape == env.observation_space.shape == (6, 130, 180) and info["block_budget"] == 2
    assert counts == {2}
    observation, reward, *_, info = env.step(env.action_space.sample())
    assert {"achieved_before", "achieved_goal", "grasped_slot", "heightmap_grid"} <= set(info)
    assert reward == structure_outcome(
        info["achieved_before"],
        info["achieved_goal"],
        env.unwrapped.task.desired_goal(),
        None if info["grasped_slot"] < 0 else info["grasped_slot"],
    )
    env.close()


def test_the_learner_stores_hindsight_copies_and_keeps_its_budget_across_a_save(structure_config, tmp_path):
    from panda_grasp_env.agents.learning.config import make_vec_env
    from panda_grasp_env.agents.learning.training import build_model

    env = make_vec_env(structure_config)
    model = build_model(structure_config, env, None)
    assert isinstance(model, GoalHeightmapDQN) and model.q_net.goal and model.block_budget == 2
    model.learn(12)
    # Every real step is stored once, plus up to two relabelled copies once its episode ended.
    assert model.replay_buffer.size() >= 12
    model.block_budget = 4
    model.save(tmp_path / "model.zip")
    loaded = GoalHeightmapDQN.load(tmp_path / "model.zip", env=env)
    assert loaded.block_budget == 4 and loaded._episodes == {}
    loaded.learn(1, reset_num_timesteps=False)
    assert env.get_attr("budget") == [4]
    env.close()


def test_the_teacher_plays_first_and_its_paid_steps_are_the_demonstrations_again_after_a_save(
    structure_config, tmp_path
):
    from panda_grasp_env.agents.learning.config import make_vec_env
    from panda_grasp_env.agents.learning.training import build_model

    config = load_config(
        "configs/structure_builder_dqn.yaml",
        [
            "env_kwargs.rotations=4",
            "algo_kwargs.buffer_size=300",
            "algo_kwargs.learning_starts=1",
            "env_kwargs.max_pieces=3",
            "max_episode_steps=8",
            "algo_kwargs.teacher_episodes=2",
            "algo_kwargs.pretrain_steps=2",
            "algo_kwargs.batch_size=2",
        ],
    )
    env = make_vec_env(config)
    model = build_model(config, env, None)
    model.learn(20)
    assert model.taught_episodes == 2 and not model.teaching and model.pretrained_steps == 2
    rows = np.array(model.taught_rows)
    # Every paid step is a grasp or place that achieved something: its stored reward is positive.
    assert len(rows) >= 2 and (model.replay_buffer.rewards[rows, 0] > 0).all()
    assert model.demonstration_steps == len(rows)
    # A cube's actions repeat after a quarter turn (one of the 4 headings), a plank's after a half.
    assert len(model.taught_periods) == len(rows) and set(model.taught_periods) <= {1, 2}
    # The teacher's structures were drawn at the whole budget, the learner's at the curriculum's again.
    assert env.get_attr("budget") == [model.block_budget]
    model.save(tmp_path / "model.zip")
    model.save_replay_buffer(tmp_path / "replay.pkl")
    # A resumed run given more steps grows its buffer, the rows where they were.
    loaded = GoalHeightmapDQN.load(tmp_path / "model.zip", env=env, buffer_size=400)
    loaded.load_replay_buffer(tmp_path / "replay.pkl")
    filled = model.replay_buffer.pos
    assert loaded.replay_buffer.buffer_size == 400 and loaded.replay_buffer.pos == filled
    assert np.array_equal(loaded.replay_buffer.observations[:filled], model.replay_buffer.observations[:filled])
    loaded.learn(1, reset_num_timesteps=False)
    assert loaded.taught_rows == model.taught_rows and loaded.teacher.stride == 2
    assert th.equal(loaded._demo_actions, model._demo_actions)
    assert th.equal(loaded._demo_observations, model._demo_observations)
    assert th.equal(loaded._demo_periods, th.as_tensor(model.taught_periods))
    env.close()


@pytest.mark.unit
def test_a_resumed_builder_may_grow_its_buffer_and_never_shrink_it(structure_config):
    from dataclasses import replace

    from panda_grasp_env.agents.learning.config import check_policy_resume

    def sized(config, size):
        return replace(config, algo_kwargs={**config.algo_kwargs, "buffer_size": size})

    check_policy_resume(structure_config, sized(structure_config, 500))
    with pytest.raises(ValueError, match="buffer_size"):
        check_policy_resume(structure_config, sized(structure_config, 100))


@pytest.mark.unit
def test_goal_heightmap_dqn_needs_the_structure_task_and_the_outcome_reward(structure_config):
    raw = {"name": "x", "env_id": "PandaStructure-v0", "algo": "goal_heightmap_dqn", "total_steps": 10}
    with pytest.raises(ValueError, match="goal_heightmap_dqn only on a StructureBuild id"):
        config_from_dict(raw)
    with pytest.raises(ValueError, match="goal_heightmap_dqn only on a StructureBuild id"):
        config_from_dict({**raw, "env_id": "PandaTowerBuild-v0", "reward": "outcome"})
    assert config_from_dict({**raw, "reward": "outcome"}).algo == "goal_heightmap_dqn"
    with pytest.raises(ValueError, match="hindsight_goals"):
        GoalHeightmapDQN(HeightmapQPolicy, None, hindsight_goals=-1, _init_setup_model=False)
    with pytest.raises(ValueError, match="teacher_episodes"):
        GoalHeightmapDQN(HeightmapQPolicy, None, teacher_episodes=-1, _init_setup_model=False)
    with pytest.raises(ValueError, match="stride"):
        GoalHeightmapDQN(HeightmapQPolicy, None, teacher_stride=0, _init_setup_model=False)
    with pytest.raises(ValueError, match="goal_heightmap_dqn: margin"):
        GoalHeightmapDQN(HeightmapQPolicy, None, margin=-1, _init_setup_model=False)


def test_validation_reports_success_per_tier_and_the_curve_draws_it(structure_config, tmp_path):
    import dataclasses
    import json

    from panda_grasp_env.agents.learning.config import make_vec_env
    from panda_grasp_env.agents.learning.records import plot_curve
    from panda_grasp_env.agents.learning.training import build_model, evaluate_policy

    config = dataclasses.replace(structure_config, max_episode_steps=2)
    env = make_vec_env(config)
    metrics = evaluate_policy(build_model(config, env, None), config, 4)
    env.close()
    by_tier = metrics["trial_success_by_tier"]
    assert set(by_tier) <= {"1", "2", "3", "4"} and sum(t["n"] for t in by_tier.values()) == 4
    row = {"steps": 0, "wall_seconds": 1.0, "metrics": metrics}
    (tmp_path / "evaluations.jsonl").write_text(json.dumps(row) + "\n")
    plot_curve(tmp_path, "structures")
    assert (tmp_path / "curve.png").stat().st_size > 0
