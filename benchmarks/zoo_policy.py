"""Test RL Zoo models (SB3 zips from ``python -m rl_zoo3.train``) on held-out seeds of their env.

    python benchmarks/zoo_policy.py logs/tqc/PandaPush-v0_1/best_model.zip [more.zip ...] [--algo tqc]
        [--env PandaPush-v0] [--episodes 100] [--seed-start 1100000]

Runs each policy deterministically through ``env.step``, one episode per seed from ``--seed-start``. The
default seeds are those the final tests of this repository's own runs use: the Zoo validates on its own
episodes, never these. To choose among several saved models (``best_model.zip`` is chosen on mean
episode reward, the periodic ``rl_model_*_steps.zip`` on nothing), score them on the selection seeds
(``--seed-start 1001000 --episodes 200``, as ``train.py``'s selection does) and test only the chosen one on
the default seeds. Prints each success rate with its 95 % interval and the learning curve the Zoo
logged (``evaluations.npz`` beside the model: mean episode reward and validation success against steps).
A zip is an SB3 pickle: load only one you made.
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

from benchmarks._common import rate
from panda_grasp_env.agents.learning.config import TEST_SEED_OFFSET, TrainConfig

#: Where the held-out test seeds of this repository's own runs start (default ``eval_seed`` + offset).
TEST_SEED_START = TrainConfig.eval_seed + TEST_SEED_OFFSET


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("models", type=Path, nargs="+")
    parser.add_argument("--algo", default="tqc", choices=("tqc", "sac"))
    parser.add_argument("--env", default="PandaPush-v0")
    parser.add_argument("--episodes", type=int, default=100)
    parser.add_argument("--seed-start", type=int, default=TEST_SEED_START)
    args = parser.parse_args()
    if args.algo == "tqc":
        from sb3_contrib import TQC as Algorithm
    else:
        from stable_baselines3 import SAC as Algorithm
    if args.episodes < 1:
        parser.error(f"--episodes must be a positive number of episodes, got {args.episodes}")
    env = gym.make(f"panda_grasp_env:{args.env}")
    seeds = f"{args.seed_start}-{args.seed_start + args.episodes - 1}"
    kind = "held-out test seeds" if args.seed_start == TEST_SEED_START else "seeds"
    for path in args.models:
        model = Algorithm.load(path, env=env, device="cpu")
        successes = 0
        for seed in range(args.seed_start, args.seed_start + args.episodes):
            observation, info = env.reset(seed=seed)
            while True:
                action, _ = model.predict(observation, deterministic=True)
                observation, _, terminated, truncated, info = env.step(action)
                if terminated or truncated:
                    break
            successes += bool(info["is_success"])
        result = rate(successes, args.episodes)
        low, high = result["ci95"]
        print(
            f"{path}: {100 * result['rate']:.1f} % success ({successes}/{args.episodes}, 95 % CI "
            f"{100 * low:.1f}-{100 * high:.1f} %) on {args.env}, {kind} {seeds}"
        )
    for curve in dict.fromkeys(path.parent / "evaluations.npz" for path in args.models):
        if not curve.is_file():
            continue
        print(f"the Zoo's log {curve}:")
        logged = np.load(curve)
        successes = logged["successes"] if "successes" in logged else [None] * len(logged["timesteps"])
        for steps, rewards, won in zip(logged["timesteps"], logged["results"], successes):
            validation = "" if won is None else f", validation success {100 * float(np.mean(won)):.0f} %"
            print(f"    step {int(steps):>7}: mean episode reward {float(np.mean(rewards)):6.1f}{validation}")


if __name__ == "__main__":
    main()
