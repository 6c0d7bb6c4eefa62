"""train.py, its configs, the heightmap Q-policy and loading shipped checkpoints."""

import dataclasses
import json
import shutil
from pathlib import Path

import gymnasium as gym
import numpy as np
import pytest
import torch as th
import yaml

from panda_grasp_env.actions import PixelActions
from panda_grasp_env.agents.learning.config import OutcomeReward, TrainConfig, load_config
from panda_grasp_env.agents.learning.heightmap_policy import (
    HEIGHT_RANGE,
    EncodedHeightmap,
    FailureMemory,
    HeightmapDQN,
    HeightmapQPolicy,
    encode_heightmap,
    heading_in_image,
    holding_after,
    rotation_grid,
    sample,
)
from panda_grasp_env.agents.learning.policy_files import load_policy
from panda_grasp_env.agents.learning.records import load_best_policy, save_best_policy, ship
from panda_grasp_env.agents.learning.training import validation_score
from panda_grasp_env.agents.policies import learned
from panda_grasp_env.agents.policies.policy_agent import PolicyAgent
from panda_grasp_env.commands import train
from panda_grasp_env.perception.heightmap import HeightmapGrid
from panda_grasp_env.tasks.tower_break import BREAK_DIRECTIONS

CONFIGS = Path(__file__).resolve().parent.parent / "configs"
#: A pixel-mode DQN small enough to train for a few steps in seconds.
TINY_DQN = [
    "env_id=PandaGrasp-v0",
    "env_kwargs={obs_mode: heightmap, action_mode: pixel, heightmap_resolution: 0.016, rotations: 4}",
    "max_episode_steps=3",
    "total_steps=12",
    "algo_kwargs.learning_starts=4",
    "algo_kwargs.buffer_size=100",
    "algo_kwargs.batch_size=4",
    "eval_every=6",
    "eval_episodes=1",
    "final_eval_episodes=2",
    "checkpoint_every=6",
]


def write_config(tmp_path, **entries):
    path = tmp_path / "c.yaml"
    path.write_text(yaml.safe_dump(entries))
    return path


def test_every_shipped_config_loads():
    names = sorted(p.stem for p in CONFIGS.glob("*.yaml") if "kind: fall_dynamics" not in p.read_text())
    assert {"grasp_clutter_dqn", "push_sac_her", "lift_sac_her", "tower_break_dqn", "smoke_grasp_dqn"} <= set(names)
    for name in names:  # (the fall-dynamics config is loaded in test_falls.py, against a recorded dataset)
        assert load_config(CONFIGS / f"{name}.yaml").name == name


def test_unknown_key_fails_listing_the_valid_ones(tmp_path):
    path = write_config(tmp_path, name="x", env_id="PandaPush-v0", algo="sac", total_steps=10, learning_rate=1)
    with pytest.raises(ValueError, match=r"unknown key\(s\) \['learning_rate'\].*valid keys: .*total_steps"):
        load_config(path)
    with pytest.raises(ValueError, match=r"unknown key\(s\) \['totl_steps'\]"):
        load_config(CONFIGS / "push_sac_her.yaml", ["totl_steps=5"])


def test_a_missing_key_fails_listing_the_valid_ones(tmp_path):
    path = write_config(tmp_path, name="x", env_id="PandaPush-v0", algo="sac")
    with pytest.raises(ValueError, match=r"c.yaml lacks required key\(s\) \['total_steps'\]; valid keys: \['name'"):
        load_config(path)


@pytest.mark.parametrize(
    "override, message",
    [
        ("total_steps=-5", "total_steps=-5: expected an int >= 1"),
        ("algo=dqnn", "expected one of"),
        ("env_id=PandaFly-v0", "expected one of"),
        ("algo_kwargs.learnin_rate=0.1", r"unknown algo_kwargs \['learnin_rate'\].*valid: .*learning_rate"),
        ("vec_env=threads", "'dummy' or 'subproc'"),
        ("reward=progress", r"expected one of \['task', 'outcome'\]"),
        ("reward=outcome", "'task' unless env_id is a TowerBuild id"),
        ("her={n_sampled_goal: 4}", None),  # fine for sac
        ("algo_kwargs.learning_rate={start: 0.001, end: 0.0001}", None),
        ("algo_kwargs.learning_rate={start: 0.001, end: -1}", r"learning_rate as a positive number or \{start"),
        ("algo_kwargs.learning_rate={start: 0.001}", r"learning_rate as a positive number or \{start"),
        ("seed", "key=value"),
        ("train_env_kwargs=0.5", "train_env_kwargs=0.5: expected a mapping"),
        ("selection_episodes=99001", r"selection_episodes=99001: expected an int in \[0, 99000\]"),
        # Values of the wrong type: the key, the value and what it takes.
        ("total_steps=1.5", "config total_steps=1.5: expected an int >= 1"),
        ("n_envs=true", "config n_envs=True: expected an int >= 1"),
        ("seed=seven", "config seed='seven': expected an int >= 0"),
        ("max_minutes=soon", "config max_minutes='soon': expected a positive number or null"),
        ("name=[a]", r"config name=\['a'\]: expected letters, digits, - and _"),
        ("name=__", "config name='__': expected letters, digits, - and _"),
        ("env_kwargs=[1]", r"config env_kwargs=\[1\]: expected a mapping"),
        ("observation_keys=[proprio, 3]", r"config observation_keys=\['proprio', 3\]: expected null or a non-empty"),
        ("observation_keys=[]", r"config observation_keys=\[\]: expected null or a non-empty"),
        ("init_policy=5", "config init_policy=5: expected a checkpoint name or folder, or null"),
    ],
)
def test_bad_values_fail_before_training(override, message):
    if message is None:
        load_config(CONFIGS / "push_sac_her.yaml", [override])
        return
    with pytest.raises(ValueError, match=message):
        load_config(CONFIGS / "push_sac_her.yaml", [override])


class ScriptedTowerSteps(gym.Env):
    """Replays TowerBuild steps (primitive, block, success, stack height, is_success, height under the next
    action's cell) on a 2x2 heightmap; every action is cell (0, 0)."""

    observation_space = gym.spaces.Box(0.0, 1.0, (2, 2, 4), dtype=np.float32)
    action_space = gym.spaces.Discrete(3 * 4)

    def __init__(self, steps, first_height=0.05, reset_info=None):
        self.steps, self.first_height = steps, first_height
        self.reset_info = reset_info if reset_info is not None else {"stack_height": 1, "base": "r", "block_size": 0.05}

    def heightmap(self, height):
        return np.full((2, 2, 4), height, dtype=np.float32)

    def reset(self, seed=None, options=None):
        self.i = 0
        return self.heightmap(self.first_height), dict(self.reset_info)

    def step(self, action):
        primitive, block, success, height, done, next_height = self.steps[self.i]
        self.i += 1
        info = {
            "primitive": primitive,
            "primitive_object": block,
            "primitive_success": success,
            "stack_height": height,
            "is_success": done,
        }
        return self.heightmap(next_height), -99.0, done, False, info


def test_outcome_reward_pays_every_grasp_from_the_table_and_the_towers_progress():
    steps = [
        ("grasp", "g", True, 1, False, 0.05),  # a loose block from the table: +1
        ("place", "g", False, 1, False, 0.05),  # placed off: 0
        ("grasp", "g", True, 1, False, 0.10),  # the same block again: +1 (the task pays it only once)
        ("place", "g", True, 2, False, 0.05),  # one level: +1
        ("grasp", "", False, 2, False, 0.10),  # missed: 0
        ("grasp", "g", True, 1, False, 0.05),  # lifted the top block off the tower: -1, no grasp pay
        ("place", "g", True, 1, False, 0.10),  # set down on a loose block: 0
        ("grasp", "g", True, 1, False, 0.05),  # and grasped back from there: 0
        ("place", "g", True, 1, False, 0.05),  # 0
        ("grasp", "r", True, 1, False, 0.05),  # the base: 0
        ("place", "r", True, 1, False, 0.05),  # 0
        ("grasp", "b", True, 1, False, 0.05),  # +1
        ("place", "b", True, 3, True, 0.0),  # (scripted) two levels and the tower stands: +2 +1
    ]
    env = OutcomeReward(ScriptedTowerSteps(steps))
    env.reset(seed=0)
    assert [env.step(0)[1] for _ in steps] == [1, 0, 1, 1, 0, -1, 0, 0, 0, 0, 0, 1, 3]
    with pytest.raises(ValueError, match="stack_height, base and block_size"):
        OutcomeReward(ScriptedTowerSteps(steps, reset_info={})).reset()
    with pytest.raises(ValueError, match="action_mode='pixel' and obs_mode='heightmap'"):
        OutcomeReward(gym.make("panda_grasp_env:PandaTowerBuild-v0"))


def test_overrides_reach_into_mappings_and_read_numbers():
    config = load_config(CONFIGS / "push_sac_her.yaml", ["algo_kwargs.learning_rate=3e-4", "seed=7", "n_envs=2"])
    assert config.algo_kwargs["learning_rate"] == pytest.approx(3e-4)
    assert (config.seed, config.n_envs) == (7, 2)
    assert config.algo_kwargs["batch_size"] == 256  # untouched entries stay
    config = load_config(CONFIGS / "push_sac_her.yaml", ["env_kwargs.reward_type=dense", "max_minutes=2.5"])
    assert config.env_kwargs["reward_type"] == "dense" and config.max_minutes == 2.5
    with pytest.raises(ValueError, match=r"override 'name.first=x': 'name' is not a mapping"):
        load_config(CONFIGS / "push_sac_her.yaml", ["name.first=x"])


def test_train_cli_reports_config_errors_without_starting(tmp_path, capsys):
    code = train.main(["--config", str(CONFIGS / "push_sac_her.yaml"), "--runs", str(tmp_path), "bogus=1"])
    assert code == 2
    assert "valid keys" in capsys.readouterr().err
    assert not any(tmp_path.iterdir())  # no run folder was made


@pytest.mark.parametrize("yaw", [0.0, 0.7, 2.0, -2.5])
def test_rotation_brings_a_world_heading_onto_the_image_x_axis(yaw):
    grid = HeightmapGrid(((0.3, 0.7), (-0.2, 0.2), (0.0, 0.3)), 0.01)
    image = th.zeros(1, 1, *grid.shape)
    point = np.array([0.5, 0.0]) + 0.12 * np.array([np.cos(yaw), np.sin(yaw)])
    row, col = grid.world_to_cell(point)
    image[0, 0, row, col] = 1.0
    rotated = sample(image, rotation_grid(heading_in_image(th.tensor([yaw], dtype=th.float32)), image.shape[-1]))
    peak_row, peak_col = np.unravel_index(int(rotated[0, 0].argmax()), grid.shape)
    assert abs(peak_row - 19.5) <= 1 and abs(peak_col - (19.5 + 12)) <= 1


def blob_observation(rows=40, cols=40, centre=(12, 25), radius=3, height=0.04):
    heightmap = np.zeros((rows, cols, 4), dtype=np.float32)
    r, c = np.ogrid[:rows, :cols]
    inside = (r - centre[0]) ** 2 + (c - centre[1]) ** 2 <= radius**2
    heightmap[inside] = [0.8, 0.2, 0.2, height]
    return encode_heightmap(heightmap), inside


def tiny_policy(primitives=("grasp", "push"), used=("grasp",), rotations=4, rows=40, cols=40, refine=False):
    space = gym.spaces.Box(0, 255, (4, rows, cols), dtype=np.uint8)
    actions = gym.spaces.Discrete(len(primitives) * rotations * rows * cols)
    return HeightmapQPolicy(
        space,
        actions,
        lambda _: 1e-3,
        primitives=primitives,
        rotations=rotations,
        cell_size=0.01,
        primitives_used=used,
        refine=refine,
    )


def test_encoded_heightmap_keeps_millimetres():
    observation, inside = blob_observation(height=0.123)
    assert observation.shape == (4, 40, 40) and observation.dtype == np.uint8
    assert observation[3][inside][0] * HEIGHT_RANGE / 255 == pytest.approx(0.123, abs=5e-4)
    with pytest.raises(ValueError, match="heightmap"):
        encode_heightmap(np.zeros((40, 40, 3)))


def test_directional_command_becomes_heading_planes_the_network_reads():
    env = EncodedHeightmap(
        gym.make(
            "panda_grasp_env:PandaTowerBreakDirectional-v0",
            obs_mode="heightmap",
            action_mode="pixel",
            heightmap_resolution=0.008,
            rotations=4,
        )
    )
    observation, info = env.reset(seed=0)
    assert observation.shape == env.observation_space.shape and observation.shape[0] == 6
    cos_sin = observation[4:, 0, 0] / 127.0 - 1.0
    heading = BREAK_DIRECTIONS[info["direction"]]
    assert cos_sin == pytest.approx([np.cos(heading), np.sin(heading)], abs=0.01)
    assert (observation[4:] == observation[4:, :1, :1]).all()  # constant planes
    env.close()
    th.manual_seed(0)
    space = gym.spaces.Box(0, 255, (6, 40, 40), dtype=np.uint8)
    policy = HeightmapQPolicy(
        space,
        gym.spaces.Discrete(4 * 1600),
        lambda _: 1e-3,
        primitives=("push",),
        rotations=4,
        cell_size=0.01,
        command=True,
    )
    assert policy._get_constructor_parameters()["command"]
    heightmap = np.zeros((40, 40, 4), dtype=np.float32)
    heightmap[10:15, 20:25] = [0.8, 0.2, 0.2, 0.1]
    east, north = (th.as_tensor(encode_heightmap(heightmap, heading=h))[None] for h in (0.0, np.pi / 2))
    assert not th.allclose(policy.q_net(east), policy.q_net(north))  # the command changes the Q-values
    # A command is seen relative to each rotation's heading: rotation 1 (north) under the north command
    # scores what rotation 0 (east) scores under the east command, on a map turned by a quarter.
    turned = np.rot90(heightmap, k=1, axes=(0, 1)).copy()  # rows run along -x, columns along -y
    q_east = policy.q_net(east).view(4, 40, 40)[0]
    q_north = policy.q_net(th.as_tensor(encode_heightmap(turned, heading=np.pi / 2))[None]).view(4, 40, 40)[1]
    assert th.allclose(th.rot90(q_east, 1, (0, 1)), q_north, atol=1e-4)
    with pytest.raises(ValueError, match="6 or 7"):
        HeightmapQPolicy(
            gym.spaces.Box(0, 255, (4, 40, 40), dtype=np.uint8),
            gym.spaces.Discrete(4 * 1600),
            lambda _: 1e-3,
            primitives=("push",),
            rotations=4,
            cell_size=0.01,
            command=True,
        )


@pytest.mark.parametrize("refine", [False, True])
def test_policy_only_grasps_on_objects_and_scores_one_rotation_like_all(refine):
    th.manual_seed(0)
    policy = tiny_policy(refine=refine)
    assert (policy.q_net.refine is not None) == refine and policy._get_constructor_parameters()["refine"] == refine
    observation, inside = blob_observation()
    action, _ = policy.predict(observation, deterministic=True)
    p, r, row, col = np.unravel_index(int(action), (2, 4, 40, 40))
    assert p == 0 and inside[row, col]  # a grasp, on the blob
    batch = th.as_tensor(np.stack([observation, blob_observation(centre=(30, 8))[0]]))
    all_q = policy.q_net(batch)
    actions = th.tensor([[int(action)], [3 * 1600 + 30 * 40 + 8]])
    assert th.allclose(policy.q_net.q_at(batch, actions), all_q.gather(1, actions).flatten(), atol=1e-5)
    allowed = policy.q_net.allowed(batch[:1]).reshape(2, 4, 40, 40)
    assert not allowed[1].any()  # push is not used
    assert np.array_equal(allowed[0, 2].numpy(), inside)
    with pytest.raises(ValueError, match="primitives_used"):
        tiny_policy(used=("place",))


def test_agent_does_not_retry_a_failed_primitive_where_nothing_changed():
    th.manual_seed(0)
    policy = tiny_policy()
    observation, inside = blob_observation()
    failed = {"primitive": "grasp", "primitive_success": False}
    forgetful = PolicyAgent(policy, lambda o, i: o, "tiny")
    agent = PolicyAgent(policy, lambda o, i: o, "tiny", avoid_failures=True)
    for each in (forgetful, agent):
        each.reset(observation, {})
    first = agent.act(observation, {})
    assert forgetful.act(observation, {}) == forgetful.act(observation, failed) == first
    shape = (2, 4, 40, 40)
    tried = [np.unravel_index(first, shape)[1:]]
    for _ in range(2 * int(inside.sum()) + 2):  # every blob cell fails at both headings, then repeats begin
        p, rotation, row, col = np.unravel_index(agent.act(observation, failed), shape)
        assert p == 0 and inside[row, col]
        tried.append((rotation, row, col))
    radius = agent.memory.radius
    fresh = [
        (h, r, c)
        for i, (h, r, c) in enumerate(tried)
        if all(h % 2 != h0 % 2 or max(abs(r - r0), abs(c - c0)) > radius for h0, r0, c0 in tried[:i])
    ]
    assert len(fresh) >= 4 and tried[: len(fresh)] == fresh  # new places or headings first, then repeats
    assert agent.memory.excluded(observation).reshape(shape)[0][:, inside].all()
    raised, _ = blob_observation(height=0.08)  # the heights there changed: everything may be tried again
    assert agent.memory.excluded(raised) is None
    agent.reset(observation, {})
    assert agent.act(observation, failed) == first  # a new episode forgets


def test_failure_memory_marks_the_failed_heading_and_a_grasps_half_turn_only():
    observation, _ = blob_observation()
    memory = FailureMemory((2, 4, 40, 40), cell_size=0.01, primitives=("grasp", "push"))
    memory.record_failure(np.ravel_multi_index((0, 1, 12, 25), (2, 4, 40, 40)), observation)
    memory.record_failure(np.ravel_multi_index((1, 1, 30, 5), (2, 4, 40, 40)), observation)
    excluded = memory.excluded(observation).reshape(2, 4, 40, 40)
    assert excluded[0, [1, 3], 12, 25].all() and not excluded[0, [0, 2], 12, 25].any()  # the fingers are alike
    assert excluded[1, 1, 30, 5] and not excluded[1, [0, 2, 3], 30, 5].any()  # a push turned round is not
    assert excluded[0, 1, 12 + memory.radius, 25] and not excluded[0, 1, 13 + memory.radius, 25]
    with pytest.raises(ValueError, match="primitive names"):
        FailureMemory((2, 4, 40, 40), cell_size=0.01, primitives=("grasp",))


def test_exploration_samples_only_allowed_actions():
    import gymnasium as gym

    class Blob(gym.Env):
        observation_space = gym.spaces.Box(0, 255, (4, 40, 40), dtype=np.uint8)
        action_space = gym.spaces.Discrete(2 * 4 * 40 * 40)

        def reset(self, seed=None, options=None):
            return blob_observation()[0], {}

        def step(self, action):
            return blob_observation()[0], 0.0, True, False, {}

    small = 100  # transitions: SB3's default million would reserve ~13 GB for 4x40x40 observations
    model = HeightmapDQN(
        HeightmapQPolicy,
        Blob(),
        buffer_size=small,
        policy_kwargs={"primitives": ("grasp", "push"), "rotations": 4, "cell_size": 0.01},
    )
    model.exploration_rate = 1.0
    observation, inside = blob_observation()
    near = np.zeros_like(inside)
    for _ in range(50):
        p, _, row, col = np.unravel_index(int(model.predict(observation)[0]), (2, 4, 40, 40))
        if p == 0:
            assert inside[row, col]
        else:
            near[row, col] = True
    near_cells = round(PixelActions.NEAR / 0.01)  # pushes start at most this many cells (either axis) from the blob
    blob = np.argwhere(inside)
    starts = np.argwhere(near)
    gaps = np.abs(starts[:, None, :] - blob[None, :, :]).max(axis=2).min(axis=1)
    assert len(starts) and gaps.max() <= near_cells
    # The warm-up before learning_starts draws among the allowed actions too (SB3's draws from the whole space).
    warm = HeightmapDQN(
        HeightmapQPolicy, Blob(), buffer_size=small, learning_starts=100, policy_kwargs=model.policy_kwargs, seed=0
    )
    warm.learn(20)
    allowed = warm.q_net.allowed(th.as_tensor(observation[None]))[0].numpy()
    assert warm.replay_buffer.size() == 20 and allowed[warm.replay_buffer.actions[:20, 0, 0]].all()


@pytest.fixture(scope="module")
def finished_run(tmp_path_factory):
    """A tiny pixel-mode DQN run, trained in two sessions (the second resumes the first)."""
    runs = tmp_path_factory.mktemp("runs")
    config = str(CONFIGS / "grasp_clutter_dqn.yaml")
    assert train.main(["--config", config, "--runs", str(runs), "--no-progress", *TINY_DQN, "total_steps=6"]) == 0
    run = runs / "grasp_clutter_dqn-seed0"
    assert json.loads((run / "progress.json").read_text())["steps"] == 6
    assert train.main(["--resume", str(run), "total_steps=12", "--no-progress"]) == 0
    return run


def test_a_run_folder_holds_everything_and_resumes(finished_run):
    run = finished_run
    for name in ("config.yaml", "meta.json", "latest.zip", "replay.pkl", "curve.png", "final.json", "card.md"):
        assert (run / name).is_file(), name
    assert any((run / "tb").rglob("events.out.tfevents.*"))
    assert json.loads((run / "progress.json").read_text())["steps"] == 12
    evaluations = [json.loads(line) for line in (run / "evaluations.jsonl").read_text().splitlines()]
    assert [e["steps"] for e in evaluations] == [0, 6, 12]  # untrained, then one per session, none repeated
    meta = json.loads((run / "meta.json").read_text())
    assert meta["seed"] == 0 and "torch" in meta["versions"]
    final = json.loads((run / "final.json").read_text())
    assert final["test_seeds"][0] == final["metrics"]["seeds"][0] == 1_000_000 + 100_000  # held out from validation
    assert final["best_steps"] in (0, 6, 12) and (run / "best_policy.safetensors").is_file()
    card = (run / "card.md").read_text()
    assert "95 % CI" in card and "environment steps | 12" in card
    assert not list(run.glob("*.tmp"))


def test_a_policy_chosen_on_selection_seeds_is_tested_and_carded_as_such(finished_run, tmp_path):
    run = tmp_path / finished_run.name
    shutil.copytree(finished_run, run)
    policy, _ = load_best_policy(run)
    with pytest.raises(ValueError, match="chosen_by='luck'"):
        save_best_policy(policy, run, 12, chosen_by="luck")
    save_best_policy(policy, run, 12, chosen_by="selection")
    assert train.main(["--retest", str(run)]) == 0
    final = json.loads((run / "final.json").read_text())
    assert final["chosen_by"] == "selection" and final["best_steps"] == 12
    assert "chosen over the best periodic validation's on selection seeds" in (run / "card.md").read_text()


def test_selection_episodes_pit_the_validated_best_against_the_final_policy_before_the_test(finished_run, tmp_path):
    run = tmp_path / finished_run.name
    shutil.copytree(finished_run, run)
    policy, _ = load_best_policy(run)
    save_best_policy(policy, run, 6)  # a validated best that is not the final policy (step 12)
    assert train.main(["--resume", str(run), "selection_episodes=2", "--trust", "--no-progress"]) == 0  # a copied run
    best = json.loads((run / "best.json").read_text())
    selection = best["selection"]
    assert selection["episodes"] == 2 and selection["seeds"] == [1_001_000, 1_001_001]  # clear of validation and test
    assert (selection["validated_best"]["steps"], selection["final"]["steps"]) == (6, 12)
    final_won = validation_score(selection["final"]) > validation_score(selection["validated_best"])
    assert (best["steps"], best["chosen_by"]) == ((12, "selection") if final_won else (6, "validation"))
    final = json.loads((run / "final.json").read_text())
    assert final["best_steps"] == best["steps"] and final["selection"] == selection
    assert "Before the test, on 2 selection episodes (seeds 1001000-1001001)" in (run / "card.md").read_text()


def test_shipped_checkpoint_loads_by_name_and_refuses_other_envs(finished_run, tmp_path, monkeypatch):
    import gymnasium as gym

    monkeypatch.setattr(learned, "CHECKPOINTS", tmp_path)
    path = ship(finished_run, "tiny")
    assert learned.available_checkpoints() == ["tiny"]
    assert (path / "card.md").read_text().startswith("# tiny\n\nShipped from the run `")
    assert (path / "policy.safetensors").stat().st_size < 20e6 and not (path / "policy.zip").exists()
    agent_env = learned.Checkpoint("tiny").make_env()
    agent = learned.LearnedAgent("tiny", agent_env)
    observation, info = agent_env.reset(seed=3)
    agent.reset(observation, info)
    assert agent_env.action_space.contains(agent.act(observation, info))
    with pytest.raises(ValueError, match=r"unknown checkpoint 'nope'; available: \['tiny'\]"):
        learned.LearnedAgent("nope")
    with pytest.raises(ValueError, match="checkpoint tiny expects observations"):
        learned.LearnedAgent("tiny", gym.make("PandaPush-v0"))
    # Another id with the same spaces is fine: the check is on spaces, not on the id.
    kwargs = learned.Checkpoint("tiny").config.env_kwargs
    assert learned.LearnedAgent("tiny", gym.make("PandaGraspClutter-v0", **kwargs, n_objects=2)).name == "tiny"
    coarse = gym.make("PandaGrasp-v0", obs_mode="heightmap", action_mode="pixel", heightmap_resolution=0.008)
    with pytest.raises(ValueError, match="expects observations"):
        learned.LearnedAgent("tiny", coarse)
    assert agent.memory is None and not learned.Checkpoint("tiny").avoid_failures
    ship(finished_run, "tiny", avoid_failures=True)  # shipped again, to act with its FailureMemory
    assert learned.LearnedAgent("tiny").memory is not None
    assert learned.LearnedAgent("tiny", avoid_failures=False).memory is None
    (path / "policy.safetensors").write_bytes(b"truncated")
    with pytest.raises(ValueError, match="policy.safetensors is missing or is not the weights"):
        learned.LearnedAgent("tiny")


def test_init_policy_starts_a_run_from_a_checkpoints_weights(finished_run, tmp_path, monkeypatch):
    from panda_grasp_env.agents.learning.config import make_vec_env
    from panda_grasp_env.agents.learning.training import build_model, initial_policy_source, load_initial_policy

    monkeypatch.setattr(learned, "CHECKPOINTS", tmp_path / "checkpoints")
    ship(finished_run, "tiny")
    source = learned.Checkpoint("tiny").load_policy().state_dict()
    config = load_config(CONFIGS / "grasp_clutter_dqn.yaml", [*TINY_DQN, "init_policy=tiny"])
    env = make_vec_env(config)
    model = build_model(config, env, None)
    assert not all(th.equal(v, model.policy.state_dict()[k]) for k, v in source.items())  # random to begin with
    load_initial_policy(model, config, initial_policy_source(config))
    assert all(th.equal(v, model.policy.state_dict()[k]) for k, v in source.items())
    narrower = load_config(
        CONFIGS / "grasp_clutter_dqn.yaml", [*TINY_DQN, "init_policy=tiny", "policy_kwargs.width=16"]
    )
    with pytest.raises(ValueError, match="init_policy tiny: its network does not match"):
        load_initial_policy(build_model(narrower, env, None), narrower, initial_policy_source(narrower))
    env.close()
    with pytest.raises(ValueError, match="init_policy tiny was trained with heightmap_dqn, this run uses sac"):
        initial_policy_source(dataclasses.replace(config, algo="sac", algo_kwargs={}))
    # The same Q-policy learned from demonstrations may start from it.
    demos = {**config.algo_kwargs, "demonstrations": {"dataset": "panda_grasp_env/any-v0", "episodes": 1}}
    assert initial_policy_source(dataclasses.replace(config, algo="heightmap_dqn_demos", algo_kwargs=demos))
    with pytest.raises(ValueError, match="init_policy tiny: its action_space"):
        initial_policy_source(
            load_config(CONFIGS / "grasp_clutter_dqn.yaml", [*TINY_DQN, "init_policy=tiny", "env_kwargs.rotations=8"])
        )

    # Through train.py: a fine-tuning run starts from the checkpoint's weights (with learning_starts above
    # total_steps nothing is learned, so its policy is the checkpoint's) and records where they came from.
    runs = tmp_path / "runs"
    cli = ["--config", str(CONFIGS / "grasp_clutter_dqn.yaml"), "--runs", str(runs), "--no-progress", *TINY_DQN]
    assert train.main([*cli, "init_policy=tiny", "total_steps=6", "algo_kwargs.learning_starts=100"]) == 0
    run = runs / "grasp_clutter_dqn-seed0"
    trained = load_policy(run / "best_policy")
    assert all(th.equal(v, trained.state_dict()[k]) for k, v in source.items())
    recorded = json.loads((run / "meta.json").read_text())["init_policy"]
    assert recorded["steps"] == learned.Checkpoint("tiny").meta["steps"] and len(recorded["policy_sha256"]) == 64
    # A checkpoint that does not fit fails before anything is written, or, for another network, leaves no folder.
    assert train.main([*cli, "init_policy=nope"]) == 2
    assert train.main([*cli, "init_policy=tiny", "policy_kwargs.width=16"]) == 2
    assert sorted(p.name for p in runs.iterdir()) == ["grasp_clutter_dqn-seed0"]


@pytest.mark.parametrize("name", learned.available_checkpoints())
def test_every_shipped_checkpoint_loads_acts_and_has_its_card(name):
    checkpoint = learned.Checkpoint(name)
    assert (checkpoint.path / "policy.safetensors").stat().st_size < 20e6
    card = (checkpoint.path / "card.md").read_text()
    assert "held-out seeds" in card and (checkpoint.path / "curve.png").stat().st_size > 0
    env = checkpoint.make_env()
    agent = learned.LearnedAgent(name, env)
    observation, info = env.reset(seed=0)
    agent.reset(observation, info)
    assert env.action_space.contains(agent.act(observation, info))
    env.close()


def test_her_pipeline_runs_with_vectorised_envs(tmp_path):
    overrides = [
        "total_steps=200",
        "n_envs=2",
        "algo_kwargs.learning_starts=100",
        "algo_kwargs.buffer_size=1000",
        "eval_every=200",
        "eval_episodes=1",
        "final_eval_episodes=1",
        "checkpoint_every=200",
    ]
    config = str(CONFIGS / "lift_sac_her.yaml")  # with training envs that start some episodes holding the object
    assert train.main(["--config", config, "--runs", str(tmp_path), "--no-progress", *overrides]) == 0
    final = json.loads((tmp_path / "lift_sac_her-seed0" / "final.json").read_text())
    assert final["steps"] == 200 and final["metrics"]["episodes"] == 1
    card = (tmp_path / "lift_sac_her-seed0" / "card.md").read_text()
    curriculum = load_config(config, []).train_env_kwargs
    assert curriculum and f"training envs also {json.dumps(curriculum)}" in card


def test_train_env_kwargs_reach_the_training_envs_only():
    from panda_grasp_env.agents.learning.config import make_env, make_vec_env

    config = load_config(CONFIGS / "lift_sac_her.yaml", ["n_envs=2", "train_env_kwargs={start_in_hand: 0.5}"])
    training = make_vec_env(config)
    assert [e.unwrapped.start_curriculum for e in training.envs] == [{"in_hand": 0.5}] * 2
    evaluation = make_env(config)
    assert evaluation.unwrapped.start_curriculum == {} and evaluation.unwrapped.action_mode == "ee_delta"
    training.close()
    evaluation.close()


def test_learning_rate_decays_linearly_over_total_steps_also_when_resumed(tmp_path, monkeypatch):
    decay = "algo_kwargs.learning_rate={start: 0.001, end: 0.0001}"
    config = str(CONFIGS / "grasp_clutter_dqn.yaml")
    cli = ["--config", config, "--runs", str(tmp_path), "--no-progress", *TINY_DQN, decay, "total_steps=6"]
    assert train.main(cli) == 0
    rates = []
    original = HeightmapDQN.train

    def recording_train(self, *args, **kwargs):
        original(self, *args, **kwargs)
        rates.append((self.num_timesteps, self.policy.optimizer.param_groups[0]["lr"]))

    monkeypatch.setattr(HeightmapDQN, "train", recording_train)
    assert train.main(["--resume", str(tmp_path / "grasp_clutter_dqn-seed0"), "total_steps=12", "--no-progress"]) == 0
    assert [steps for steps, _ in rates] == [7, 8, 9, 10, 11, 12]
    for steps, rate in rates:  # progress counts from the run's first step to its total_steps, across sessions
        assert rate == pytest.approx(1e-3 + (1e-4 - 1e-3) * steps / 12)

    rates.clear()  # a resumed run may change the learner's settings: they reach the loaded model
    run = str(tmp_path / "grasp_clutter_dqn-seed0")
    assert train.main(["--resume", run, "total_steps=14", "algo_kwargs.learning_rate=0.0005", "--no-progress"]) == 0
    assert rates == [(13, pytest.approx(5e-4)), (14, pytest.approx(5e-4))]
    assert "learning_rate: 0.0005" in (tmp_path / "grasp_clutter_dqn-seed0" / "config.yaml").read_text()
    sessions = json.loads((tmp_path / "grasp_clutter_dqn-seed0" / "meta.json").read_text())["resumed"]
    assert [(r["after_steps"], r["overrides"]) for r in sessions] == [
        (6, ["total_steps=12"]),
        (12, ["total_steps=14", "algo_kwargs.learning_rate=0.0005"]),
    ]  # config.yaml keeps only the latest values: the card tells the stages apart
    card = (tmp_path / "grasp_clutter_dqn-seed0" / "card.md").read_text()
    assert (
        "| sessions | resumed at step 6 with `total_steps=12`; at step 12 with `total_steps=14` "
        "`algo_kwargs.learning_rate=0.0005` |" in card
    )


def test_resume_refuses_changes_to_what_built_the_model(finished_run, capsys):
    saved = (finished_run / "config.yaml").read_text()
    for override in ("seed=5", "policy_kwargs.rotations=8", "algo_kwargs.buffer_size=7"):
        assert train.main(["--resume", str(finished_run), override, "--no-progress"]) == 2
        assert "a resumed run cannot change" in capsys.readouterr().err
    assert (finished_run / "config.yaml").read_text() == saved


@pytest.mark.slow
def test_smoke_training_learns_to_grasp(tmp_path):
    """CI's smoke training (~4 min on 2 cores): 300 grasps in the pixel mode lift grasp success on held-out seeds."""
    config = str(CONFIGS / "smoke_grasp_dqn.yaml")
    assert train.main(["--config", config, "--runs", str(tmp_path), "--no-progress"]) == 0
    run = tmp_path / "smoke_grasp_dqn-seed0"
    evaluations = [json.loads(line) for line in (run / "evaluations.jsonl").read_text().splitlines()]
    untrained = evaluations[0]["metrics"]["grasp_success"]["rate"]
    trained = json.loads((run / "final.json").read_text())["metrics"]["grasp_success"]["rate"]
    assert evaluations[0]["steps"] == 0
    assert trained >= untrained + 0.15 and trained >= 0.55, (untrained, trained)


def test_evaluate_runs_a_shipped_checkpoint_by_name_and_skips_other_tasks(finished_run, tmp_path, monkeypatch):
    from panda_grasp_env.commands import evaluate

    monkeypatch.setattr(learned, "CHECKPOINTS", tmp_path / "checkpoints")
    ship(finished_run, "tiny")
    out = tmp_path / "results"
    args = ["--agents", "tiny,random", "--tasks", "Grasp,Push", "--seeds", "1", "--no-video", "--out", str(out)]
    assert evaluate.main(args) == 0
    results = json.loads((out / "results.json").read_text())
    assert set(results["metrics"]) == {"tiny/Grasp", "random/Grasp", "random/Push"}
    report = (out / "report.md").read_text()
    assert "skipped tiny/Push: checkpoint tiny was trained for Grasp" in report
    assert (out / "curve_tiny.png").exists()
    with pytest.raises(SystemExit):
        evaluate.main(["--agents", "nope", "--out", str(out)])


def test_evaluation_plays_the_seeds_it_is_given():
    """Validation and the held-out test must be different episodes: evaluate_policy seeds from first_seed."""
    from panda_grasp_env.agents.learning.training import evaluate_policy

    class Still:  # a stand-in policy: do nothing
        def predict(self, observation, deterministic=True):
            return np.zeros(4, dtype=np.float32), None

    config = TrainConfig(name="s", env_id="PandaPush-v0", algo="sac", total_steps=1, max_episode_steps=2, eval_seed=7)
    assert evaluate_policy(Still(), config, 2)["seeds"] == [7, 8]
    assert evaluate_policy(Still(), config, 2, first_seed=100)["seeds"] == [100, 101]


def test_holding_plane_switches_the_masks_between_grasp_and_place():
    import gymnasium as gym

    heightmap = np.zeros((40, 40, 4), dtype=np.float32)
    heightmap[10:15, 10:15] = [0.8, 0.2, 0.2, 0.05]
    assert holding_after({"primitive": "grasp", "primitive_success": True})
    assert not holding_after({"primitive": "place", "primitive_success": True})
    assert not holding_after({"primitive": "grasp", "primitive_success": False}) and not holding_after({})
    holding, empty = encode_heightmap(heightmap, True), encode_heightmap(heightmap, False)
    assert holding.shape == (5, 40, 40) and holding[4].min() == 255 and empty[4].max() == 0
    primitives = ("grasp", "place", "push")
    space = gym.spaces.Box(0, 255, (5, 40, 40), dtype=np.uint8)
    policy = HeightmapQPolicy(
        space,
        gym.spaces.Discrete(3 * 4 * 1600),
        lambda _: 1e-3,
        primitives=primitives,
        rotations=4,
        cell_size=0.01,
        primitives_used=("grasp", "place"),
    )
    allowed = policy.q_net.allowed(th.as_tensor(np.stack([holding, empty]))).reshape(2, 3, 4, 40, 40)
    assert allowed[0, 1].any() and not allowed[0, 0].any()  # holding: place only
    assert allowed[1, 0].any() and not allowed[1, 1].any()  # empty hand: grasp only
    assert not allowed[:, 2].any()  # push unused
    with pytest.raises(ValueError, match="place needs the holding plane"):
        tiny_policy(primitives=primitives, used=("grasp", "place"))


def test_retest_runs_the_final_test_again_without_training(finished_run, capsys):
    before = json.loads((finished_run / "final.json").read_text())
    (finished_run / "final.json").unlink()
    assert train.main(["--retest", str(finished_run)]) == 0
    after = json.loads((finished_run / "final.json").read_text())
    assert after["metrics"] == before["metrics"] and after["steps"] == 12  # deterministic, same seeds
    assert json.loads((finished_run / "progress.json").read_text())["steps"] == 12  # nothing trained
    assert "final: success" in capsys.readouterr().out


def test_retest_of_a_corrupt_policy_is_one_error_line(finished_run, tmp_path, capsys):
    import shutil

    broken = tmp_path / "broken"
    shutil.copytree(finished_run, broken)
    (broken / "best_policy.safetensors").write_bytes(b"not weights")
    assert train.main(["--retest", str(broken)]) == 2
    err = capsys.readouterr().err
    assert err.startswith("error: cannot load the best policy of") and "best_policy.safetensors" in err
    assert "Traceback" not in err


def test_resume_from_a_corrupt_checkpoint_is_one_error_line_and_no_session(finished_run, tmp_path, capsys):
    import shutil

    broken = tmp_path / "broken"
    shutil.copytree(finished_run, broken)
    (broken / "latest.zip").write_bytes(b"not a zip")
    sessions = json.loads((broken / "meta.json").read_text())["resumed"]
    assert train.main(["--resume", str(broken), "total_steps=14", "--no-progress", "--trust"]) == 2
    err = capsys.readouterr().err
    assert err.startswith("error: cannot resume") and "Traceback" not in err
    assert json.loads((broken / "meta.json").read_text())["resumed"] == sessions  # the failed session left no record


def test_resume_rebuilds_a_policy_pickled_under_a_retired_module_name(finished_run, tmp_path):
    """Checkpoints written before the package's import names moved pickle their policy class as
    ``agents.heightmap_policy:...``; a resume builds the config's own class instead of unpickling that name."""
    import base64
    import pickle
    import shutil
    import sys
    import types
    import zipfile

    retired = types.ModuleType("retired_agents")
    retired.HeightmapQPolicy = type("HeightmapQPolicy", (), {"__module__": "retired_agents"})
    sys.modules["retired_agents"] = retired
    try:
        serialized = base64.b64encode(pickle.dumps(retired.HeightmapQPolicy)).decode()
    finally:
        del sys.modules["retired_agents"]
    old = tmp_path / "old"
    shutil.copytree(finished_run, old)
    with zipfile.ZipFile(finished_run / "latest.zip") as source, zipfile.ZipFile(old / "latest.zip", "w") as target:
        for item in source.infolist():
            content = source.read(item)
            if item.filename == "data":
                data = json.loads(content)
                data["policy_class"][":serialized:"] = serialized
                content = json.dumps(data).encode()
            target.writestr(item, content)
    assert train.main(["--resume", str(old), "total_steps=14", "--no-progress", "--trust"]) == 0
    with zipfile.ZipFile(old / "latest.zip") as rewritten:
        policy_class = json.loads(rewritten.read("data"))["policy_class"]
    assert policy_class["__module__"] == "panda_grasp_env.agents.learning.heightmap_policy"
    assert isinstance(load_policy(old / "best_policy"), HeightmapQPolicy)


def test_retest_runs_on_a_shipped_checkpoint_too(finished_run, tmp_path, monkeypatch):
    monkeypatch.setattr(learned, "CHECKPOINTS", tmp_path)
    shipped = ship(finished_run, "tiny")  # policy.zip, no progress.json: the run's totals are in final.json
    before = json.loads((shipped / "final.json").read_text())
    assert train.main(["--retest", str(shipped)]) == 0
    after = json.loads((shipped / "final.json").read_text())
    assert after["metrics"] == before["metrics"] and after["steps"] == before["steps"] == 12
    assert not (shipped / "progress.json").exists()
    assert after["test_commit"]  # the code the test ran on, which a card names when it differs from training's
    # The figures it replaces stay beside the new ones (final.json and the card), newest last.
    assert after["earlier"][-1] == {"test_commit": before["test_commit"], "metrics": before["metrics"]}
    card = (shipped / "card.md").read_text()
    assert "Earlier tests of this policy" in card
    assert card.startswith("# tiny\n\nShipped from the run `")  # named as shipped, not as the run was
    # Shipped to act with its FailureMemory, it is retested so, and its card says which test had it.
    shipped = ship(finished_run, "tiny", avoid_failures=True)
    assert train.main(["--retest", str(shipped)]) == 0
    assert train.main(["--retest", str(shipped)]) == 0
    final = json.loads((shipped / "final.json").read_text())
    assert final["avoid_failures"] and final["earlier"][-1]["avoid_failures"]
    assert "avoid_failures" not in final["earlier"][0]  # the run's own test, without it
    card = (shipped / "card.md").read_text()
    assert "It acts as shipped, with its `FailureMemory`" in card and ", with its `FailureMemory`:" in card
    assert "disturbed objects per action" in card  # collateral, for primitive tasks


def test_maskable_ppo_cnn_policy_takes_the_encoded_heightmap_as_it_is():
    """SB3's off-the-shelf CnnPolicy on pixel_factored, through the wrapper the docs name: uint8, channels first.
    (benchmarks/cnn_policy.py runs it for 256 steps and prints its parameter count and peak memory.)"""
    from sb3_contrib import MaskablePPO
    from stable_baselines3.common.preprocessing import is_image_space

    from panda_grasp_env.agents.learning.heightmap_policy import EncodedHeightmap

    raw = gym.make(
        "panda_grasp_env:PandaGrasp-v0",
        action_mode="pixel_factored",
        obs_mode="heightmap",
        heightmap_resolution=0.004,
        rotations=4,
    )
    assert not is_image_space(raw.observation_space)  # float32, channels last: CnnPolicy fails on it
    env = EncodedHeightmap(raw)
    assert env.observation_space.shape == (4, 112, 112) and is_image_space(env.observation_space)
    model = MaskablePPO("CnnPolicy", env, n_steps=16, batch_size=8, n_epochs=1, seed=0, device="cpu")
    model.learn(16)
    assert model.num_timesteps == 16
    env.close()
