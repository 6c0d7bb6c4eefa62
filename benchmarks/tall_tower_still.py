"""The tall-tower page's figure: the front camera on towers of 6 and 8 blocks.

    python benchmarks/tall_tower_still.py [--seed 6900000] [--out docs/images/tall_towers.png]

Three frames side by side, each the env's ``rgb_array`` render (front camera, 400 x 300):

1. the 6-block tower the planned agent built on ``TowerBuild6``, seed ``--seed``;
2. ``TowerBreak8``'s 40 cm tower at reset, seed ``--seed``;
3. the same scene after the planned agent's push (the frame when the step returns: blocks at rest).

Prints which seeds and how many actions each frame took.  Nothing here is a figure of merit: the rates are
``evaluate.py``'s (docs/tall-towers.md).
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))
import panda_grasp_env  # noqa: E402, F401  (first: it chooses MUJOCO_GL before mujoco is imported)

# isort: split

import gymnasium as gym
import numpy as np

from panda_grasp_env.agents.evaluation.benchmarks import BENCHMARKS
from panda_grasp_env.agents.evaluation.protocol import PERCEPTION, baseline

RENDER = {"render_mode": "rgb_array", "render_size": (400, 300)}


def play(env: gym.Env, agent, seed: int) -> tuple[bool, int]:
    """One episode from ``seed``; whether it succeeded and how many actions it took."""
    observation, info = env.reset(seed=seed)
    agent.reset(observation, info)
    for actions in range(1, 10_000):
        observation, _, terminated, truncated, info = env.step(agent.act(observation, info))
        if terminated or truncated:
            return bool(info["is_success"]), actions
    raise RuntimeError("an episode without a step limit")


def planned_tower(seed: int) -> np.ndarray:
    benchmark = BENCHMARKS["TowerBuild6"]
    env = gym.make(f"panda_grasp_env:{benchmark.env_id}", **benchmark.options, **PERCEPTION, **RENDER)
    built, actions = play(env, baseline("TowerBuild6")(env, seed, False), seed)
    print(f"planned on TowerBuild6, seed {seed}: {'built' if built else 'not built'} in {actions} actions")
    frame = env.render()
    env.close()
    return frame


def planned_break(seed: int) -> tuple[np.ndarray, np.ndarray]:
    benchmark = BENCHMARKS["TowerBreak8"]
    env = gym.make(f"panda_grasp_env:{benchmark.env_id}", **benchmark.options, **PERCEPTION, **RENDER)
    observation, info = env.reset(seed=seed)
    standing = env.render()
    agent = baseline("TowerBreak8")(env, seed, False)
    agent.reset(observation, info)
    _, _, _, _, info = env.step(agent.act(observation, info))
    print(f"planned on TowerBreak8, seed {seed}: push {info['primitive_reason']}, success {info['is_success']}")
    fallen = env.render()
    env.close()
    return standing, fallen


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--seed", type=int, default=6_900_000)
    parser.add_argument("--out", type=Path, default=Path("docs/images/tall_towers.png"))
    args = parser.parse_args()
    import imageio.v3 as iio

    frames = [planned_tower(args.seed), *planned_break(args.seed)]
    args.out.parent.mkdir(parents=True, exist_ok=True)
    iio.imwrite(args.out, np.concatenate(frames, axis=1))
    print(f"wrote {args.out}")


if __name__ == "__main__":
    main()
