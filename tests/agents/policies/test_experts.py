"""The scripted low-level experts act through ee_delta from the observation and solve Lift, Push and Stack."""

import gymnasium as gym
import numpy as np
import pytest

from panda_grasp_env.agents.evaluation.episodes import make_agent, make_env, play_episode
from panda_grasp_env.agents.evaluation.protocol import EpisodeSpec, skip_reason
from panda_grasp_env.agents.policies.experts import LiftExpert
from panda_grasp_env.agents.policies.registry import EXPERTS

pytestmark = pytest.mark.unit  # every test here is fast: the unit tier (python -m pytest -m unit)


@pytest.mark.parametrize("task", sorted(EXPERTS))
def test_each_expert_solves_its_task_through_the_benchmark_loop(task):
    # Examples, not a rate (the rates are measured on 100 held-out seeds, docs/agents.md).  Seed 11's Stack
    # block lies 38 degrees to the fixed closing axis and is held by its corners: a known failure.
    for seed in (12, 13):
        spec = EpisodeSpec("expert", task, seed)
        env = make_env(spec)
        result = play_episode(env, make_agent(spec, env), spec)["result"]
        assert result["success"], (task, seed)
        env.close()


def test_the_expert_reads_only_the_observation_and_says_what_it_needs():
    env = gym.make("panda_grasp_env:PandaGrasp-v0", action_mode="ee_delta")
    observation, info = env.reset(seed=0)
    expert = LiftExpert()
    expert.reset(observation, info)
    action = expert.act(observation, info)
    assert action.shape == (4,) and action.dtype == np.float32 and env.action_space.contains(action)
    with pytest.raises(ValueError, match="goal-conditioned Dict observation"):
        expert.reset(observation["observation"], info)
    assert skip_reason("expert", "TowerBuild") is not None and skip_reason("expert", "Stack") is None
