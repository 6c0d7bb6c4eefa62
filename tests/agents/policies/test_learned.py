"""Shipped learned policies (``agents/policies/learned.py``): loaded by name, acting, refusing other envs."""

import pytest

from panda_grasp_env.agents.learning.records import ship
from panda_grasp_env.agents.policies import learned


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
    assert agent.memory is None and not learned.Checkpoint("tiny").acting["avoid_failures"]
    ship(finished_run, "tiny", avoid_failures=True)  # shipped again, to act with its FailureMemory
    assert learned.LearnedAgent("tiny").memory is not None
    assert learned.LearnedAgent("tiny", acting={"avoid_failures": False}).memory is None
    with pytest.raises(ValueError, match="unknown acting rules"):
        learned.LearnedAgent("tiny", acting={"avoid_falls": True})
    with pytest.raises(ValueError, match="unknown acting rules"):
        ship(finished_run, "tiny", avoid_falls=True)
    (path / "policy.safetensors").write_bytes(b"truncated")
    with pytest.raises(ValueError, match="policy.safetensors is missing or is not the weights"):
        learned.LearnedAgent("tiny")


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
