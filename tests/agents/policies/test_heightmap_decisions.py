"""The shipped heightmap DQNs choose the recorded actions on recorded observations.

``tests/data/heightmap_decisions.npz`` holds encoded heightmaps met while each shipped policy acted in its
env, and the action it chose on each (``benchmarks/heightmap_decisions.py --record``).  A faster Q-network
(batched rotations, cached sampling grids, a separable mask filter) must not change one of them.
"""

from __future__ import annotations

import numpy as np
import pytest
from testkit import DATA

from panda_grasp_env.agents.learning.config import HEIGHTMAP_ALGORITHMS
from panda_grasp_env.agents.policies.learned import Checkpoint, available_checkpoints

RECORDED = DATA / "heightmap_decisions.npz"


def recorded() -> dict[str, tuple[np.ndarray, np.ndarray]]:
    with np.load(RECORDED) as data:
        names = sorted({key.split("/")[0] for key in data.files})
        return {name: (data[f"{name}/observations"], data[f"{name}/actions"]) for name in names}


DECISIONS = recorded()


@pytest.mark.unit
def test_the_record_covers_every_shipped_heightmap_policy():
    shipped = {name for name in available_checkpoints() if Checkpoint(name).config.algo in HEIGHTMAP_ALGORITHMS}
    assert shipped == set(DECISIONS) and len(shipped) >= 3
    assert sum(len(actions) for _, actions in DECISIONS.values()) >= 200


@pytest.mark.parametrize("name", sorted(DECISIONS))
def test_policy_chooses_the_recorded_actions(name):
    observations, actions = DECISIONS[name]
    policy = Checkpoint(name).load_policy()
    chosen = [int(policy.predict(observation, deterministic=True)[0]) for observation in observations]
    assert chosen == actions.tolist()
