"""What tests in different folders share: the checkout's paths, the falling-tower recording's and the tiny
training run's settings and a small heightmap Q-policy with an observation to show it.  (``tests/`` is on ``sys.path`` through its conftest.)"""

from pathlib import Path

import gymnasium as gym
import numpy as np

from panda_grasp_env.agents.learning.heightmap_observations import encode_heightmap
from panda_grasp_env.agents.learning.heightmap_policy import HeightmapQPolicy

#: The checkout's root, its shipped training configs and the tests' recorded data.
ROOT = Path(__file__).resolve().parents[1]
CONFIGS = ROOT / "configs"
DATA = ROOT / "tests" / "data"

#: The falling-tower recording the recorder's and the fall model's tests share (``RecorderSettings`` keys; the
#: conftest's ``fall_dataset`` records 10 sequences of it).
FALL_RECORDING = {"frames": 10, "shard_size": 2, "seed": 7}

#: A pixel-mode DQN small enough to train for a few steps in seconds (``train.py`` overrides).
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


def blob_observation(rows=40, cols=40, centre=(12, 25), radius=3, height=0.04):
    """An encoded heightmap (channels-first uint8) with one red disc of ``height`` metres, and the disc's mask."""
    heightmap = np.zeros((rows, cols, 4), dtype=np.float32)
    r, c = np.ogrid[:rows, :cols]
    inside = (r - centre[0]) ** 2 + (c - centre[1]) ** 2 <= radius**2
    heightmap[inside] = [0.8, 0.2, 0.2, height]
    return encode_heightmap(heightmap), inside


def tiny_policy(primitives=("grasp", "push"), used=("grasp",), rotations=4, rows=40, cols=40, refine=False):
    """An untrained heightmap Q-policy over 1 cm cells, for observations from :func:`blob_observation`."""
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
