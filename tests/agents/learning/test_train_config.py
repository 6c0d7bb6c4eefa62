"""The training config (``agents/learning/config.py``): checked keys and values, overrides, the envs it
describes and the outcome reward."""

import gymnasium as gym
import numpy as np
import pytest
import yaml
from testkit import CONFIGS

from panda_grasp_env.agents.learning.config import OutcomeReward, load_config
from panda_grasp_env.commands import train

pytestmark = pytest.mark.unit  # every test here is fast: the unit tier (python -m pytest -m unit)


def write_config(tmp_path, **entries):
    path = tmp_path / "c.yaml"
    path.write_text(yaml.safe_dump(entries))
    return path


def test_every_shipped_config_loads():
    names = sorted(p.stem for p in CONFIGS.glob("*.yaml") if "kind: fall_dynamics" not in p.read_text())
    assert {"grasp_clutter_dqn", "push_sac_her", "lift_sac_her", "tower_break_dqn", "smoke_grasp_dqn"} <= set(names)
    for name in names:  # (the fall-dynamics config is loaded in test_falls.py, against a recorded dataset)
        assert load_config(CONFIGS / f"{name}.yaml").name == name


def test_no_shipped_config_or_checkpoint_trains_on_the_named_structures():
    """The named suite is test-only: a training may build random structures (``structure: random``), never one
    of the suite's, whether named or given as a mapping (``configs/`` and every shipped checkpoint's
    config.yaml, recursively).  The one exception says so in its name: BuilderBench's training-wheels baseline
    (``configs/training_wheels/``, checkpoints ``training_wheels_*``) trains on one named structure by design."""
    from testkit import ROOT

    from panda_grasp_env.model.structure_suite import SUITE

    def strings(value):
        if isinstance(value, dict):
            for key, item in value.items():
                yield str(key)
                yield from strings(item)
        elif isinstance(value, list):
            for item in value:
                yield from strings(item)
        elif isinstance(value, str):
            yield value

    files = [*CONFIGS.rglob("*.yaml"), *(ROOT / "agents" / "checkpoints").rglob("config.yaml")]
    assert len(files) > 20
    wheels = [path for path in files if "training_wheels" in path.parts]
    wheels += [path for path in files if path.parent.name.startswith("training_wheels_")]
    assert wheels and all(yaml.safe_load(path.read_text())["name"].startswith("training_wheels_") for path in wheels)
    files = [path for path in files if path not in wheels]
    used = {path.name: set(strings(yaml.safe_load(path.read_text()))) & set(SUITE) for path in files}
    assert {name: names for name, names in used.items() if names} == {}


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
        ("reward=outcome", "'task' unless env_id is a TowerBuild or StructureBuild id"),
        ("her={n_sampled_goal: 4}", None),  # fine for sac
        ("algo_kwargs.learning_rate={start: 0.001, end: 0.0001}", None),
        ("algo_kwargs.learning_rate={start: 0.001, end: -1}", r"learning_rate as a positive number or \{start"),
        ("algo_kwargs.learning_rate={start: 0.001}", r"learning_rate as a positive number or \{start"),
        ("seed", "is not KEY=VALUE"),
        ("seed=[1,", r"the value is not YAML \(expected the node content"),
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


def test_train_env_kwargs_reach_the_training_envs_only():
    from panda_grasp_env.agents.learning.config import make_env, make_vec_env

    config = load_config(CONFIGS / "lift_sac_her.yaml", ["n_envs=2", "train_env_kwargs={start_in_hand: 0.5}"])
    training = make_vec_env(config)
    assert [e.unwrapped.start_curriculum for e in training.envs] == [{"in_hand": 0.5}] * 2
    evaluation = make_env(config)
    assert evaluation.unwrapped.start_curriculum == {} and evaluation.unwrapped.action_mode == "ee_delta"
    training.close()
    evaluation.close()
