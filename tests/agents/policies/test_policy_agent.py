"""An SB3 policy as an agent (``agents/policies/policy_agent.py``)."""

import numpy as np
import pytest
import torch as th
from testkit import blob_observation, tiny_policy

from panda_grasp_env.agents.policies.policy_agent import PolicyAgent

pytestmark = pytest.mark.unit  # every test here is fast: the unit tier (python -m pytest -m unit)


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


def test_agent_centring_on_faces_moves_its_grasps_to_the_blocks_centre():
    th.manual_seed(0)
    policy = tiny_policy()
    observation, inside = blob_observation()  # a disc of 1 cm cells, about one 5 cm block face, centre (12, 25)
    agent = PolicyAgent(policy, lambda o, i: o, "tiny", centre_on_faces=True)
    with pytest.raises(ValueError, match="block_size"):
        agent.reset(observation, {})
    agent.reset(observation, {"block_size": 0.05})
    chosen = np.unravel_index(PolicyAgent(policy, lambda o, i: o, "tiny").act(observation, {}), (2, 4, 40, 40))
    primitive, rotation, row, col = np.unravel_index(agent.act(observation, {}), (2, 4, 40, 40))
    assert (primitive, rotation) == tuple(chosen[:2]) and (row, col) == (12, 25)
