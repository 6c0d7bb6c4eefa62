"""How well can anything build through the ``pixel`` actions the structure learner uses?  The pixel-place oracle
(``agents/policies/pixel_oracle.py``) knows every piece's pose and builds through those actions.  ``--stride 4``
rounds its aims to the network's quarter-resolution grid (every 4th cell, 16 mm), as its scores are upsampled
from; ``--stride 2`` to the refined network's (every 2nd cell, 8 mm).

    python benchmarks/pixel_place_ceiling.py [--episodes 20] [--seed-start 5000000] [--rotations 32] [--stride 1]

Prints trial success with its 95 % Wilson interval, per tier, and the place failures.  Seeds 5000000 on are the
generated structures of tiers 1-4 with up to 6 pieces (configs/structure_builder_dqn.yaml's env): no training,
validation or test seed of that config.
"""

from __future__ import annotations

import argparse
import sys
from collections import Counter
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))
import panda_grasp_env  # noqa: E402, F401  (first: it chooses MUJOCO_GL before mujoco is imported)

# isort: split

import gymnasium as gym

from panda_grasp_env.agents.evaluation.metrics import wilson
from panda_grasp_env.agents.policies.pixel_oracle import PixelPlaceOracle

BOUNDS = ((0.24, 0.76), (-0.36, 0.36), (0.0, 0.45))


def play(env: gym.Env, seed: int, stride: int) -> tuple[bool, int, Counter]:
    observation, info = env.reset(seed=seed)
    oracle = PixelPlaceOracle(stride)
    oracle.start(observation["desired_goal"], info["action_layout"], info["n_targets"])
    tier = int(info["tier"])
    failures: Counter = Counter()
    while (action := oracle.next_action(observation["achieved_goal"])) is not None:
        observation, _, terminated, truncated, info = env.step(action)
        if not info["primitive_success"]:
            failures[f"{info['primitive']}: {info['primitive_reason']}"] += 1
        if terminated or truncated:
            break
    return bool(info["is_success"]), tier, failures


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--episodes", type=int, default=20)
    parser.add_argument("--seed-start", type=int, default=5_000_000)
    parser.add_argument("--rotations", type=int, default=32)
    parser.add_argument(
        "--stride", type=int, default=1, help="cells between the aims allowed: 1, 2 (the refined network) or 4"
    )
    args = parser.parse_args()
    env = gym.make(
        "PandaStructure-v0",
        obs_mode="heightmap",
        action_mode="pixel",
        heightmap_bounds=BOUNDS,
        heightmap_resolution=0.004,
        rotations=args.rotations,
        structure="random",
        tiers=[1, 2, 3, 4],
        max_pieces=6,
        max_episode_steps=30,
    )
    by_tier: dict[int, list[bool]] = {}
    failures: Counter = Counter()
    for seed in range(args.seed_start, args.seed_start + args.episodes):
        success, tier, failed = play(env, seed, args.stride)
        by_tier.setdefault(tier, []).append(success)
        failures.update(failed)
    won = [s for results in by_tier.values() for s in results]
    low, high = wilson(sum(won), len(won))
    print(
        f"rotations {args.rotations}, aims every {args.stride} cell(s) ({4 * args.stride} mm), seeds "
        f"{args.seed_start}-{args.seed_start + args.episodes - 1}"
    )
    print(f"trial success {sum(won)}/{len(won)} ({100 * low:.0f}-{100 * high:.0f} %)")
    for tier in sorted(by_tier):
        print(f"  tier {tier}: {sum(by_tier[tier])}/{len(by_tier[tier])}")
    print(f"failed primitives: {dict(failures)}")


if __name__ == "__main__":
    main()
