"""The pixel-place oracle: which of its actions repeat after a quarter turn and which after a half."""

import numpy as np
import pytest

from panda_grasp_env.agents.policies.pixel_oracle import PixelPlaceOracle
from panda_grasp_env.env import PandaEnv

# Two cubes 1 cm apart and a plank across them (structure frame, metres).
GATE = {
    "name": "test_gate",
    "pieces": [
        {"kind": "cube", "position": [-0.03, 0.0, 0.025]},
        {"kind": "cube", "position": [0.03, 0.0, 0.025]},
        {"kind": "plank", "position": [0.0, 0.0, 0.075]},
    ],
}


@pytest.mark.unit
def test_a_cube_repeats_after_a_quarter_turn_unless_placed_beside_a_built_piece():
    env = PandaEnv(task="StructureBuild", structure=GATE, obs_mode="heightmap", action_mode="pixel", rotations=32)
    observation, info = env.reset(seed=0)
    oracle = PixelPlaceOracle(stride=2)
    oracle.start(observation["desired_goal"], info["action_layout"], info["n_targets"])
    primitives = list(info["action_layout"]["primitives"])
    steps = []
    # The plan does not depend on the outcome, so the start's poses serve for every step.
    while (action := oracle.next_action(observation["achieved_goal"])) is not None:
        primitive = np.unravel_index(action, tuple(info["action_layout"]["shape"]))[0]
        steps.append((primitives[primitive], oracle.repeat_turn))
    quarter, half = np.pi / 2, np.pi
    # The first cube stands alone; the second is placed beside it, fingers kept off it; a plank has two sides.
    assert steps == [
        ("grasp", quarter),
        ("place", quarter),
        ("grasp", quarter),
        ("place", half),
        ("grasp", half),
        ("place", half),
    ]
    env.close()
