"""Test an RL Zoo model (an SB3 zip from ``python -m rl_zoo3.train``) on held-out seeds of its env.

    python benchmarks/zoo_policy.py runs/zoo/logs/tqc/PandaPush-v0_1/best_model.zip [--algo tqc]
        [--env PandaPush-v0] [--episodes 100] [--seed-start 1100000]

Runs the policy deterministically through ``env.step``, one episode per seed from ``--seed-start``. The
default seeds are those the final tests of this repository's own runs use: the Zoo validates on its own
episodes, never these. Prints the success rate with its 95 % interval and the learning curve the Zoo
logged (``evaluations.npz`` beside the model: mean episode reward and validation success against steps).  The zip is an SB3
pickle: load only one you made.
"""

from __future__ import annotations

import argparse
import os
import sys
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))
os.environ.setdefault("MUJOCO_GL", "egl")

import gymnasium as gym
import numpy as np

from benchmarks._common import rate


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("model", type=Path)
    parser.add_argument("--algo", default="tqc", choices=("tqc", "sac"))
    parser.add_argument("--env", default="PandaPush-v0")
    parser.add_argument("--episodes", type=int, default=100)
    parser.add_argument("--seed-start", type=int, default=1_100_000)
    args = parser.parse_args()
    if args.algo == "tqc":
        from sb3_contrib import TQC as Algorithm
    else:
        from stable_baselines3 import SAC as Algorithm
    env = gym.make(f"panda_grasp_env:{args.env}")
    model = Algorithm.load(args.model, env=env, device="cpu")
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
    seeds = f"{args.seed_start}-{args.seed_start + args.episodes - 1}"
    print(f"{args.model}: {100 * result['rate']:.1f} % success ({successes}/{args.episodes}, 95 % CI "
          f"{100 * low:.1f}-{100 * high:.1f} %) on {args.env}, held-out seeds {seeds}")  # fmt: skip
    curve = args.model.parent / "evaluations.npz"
    if curve.is_file():
        logged = np.load(curve)
        successes = logged["successes"] if "successes" in logged else [None] * len(logged["timesteps"])
        for steps, rewards, won in zip(logged["timesteps"], logged["results"], successes):
            validation = "" if won is None else f", validation success {100 * float(np.mean(won)):.0f} %"
            print(f"    step {int(steps):>7}: mean episode reward {float(np.mean(rewards)):6.1f}{validation}")


if __name__ == "__main__":
    main()
