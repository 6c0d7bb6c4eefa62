"""Shipped heightmap policies with and without the agent's ``FailureMemory``, on the same seeds.

    python benchmarks/failure_memory.py [--checkpoints tower_build_dqn,grasp_clutter_dqn] [--episodes N]
                                        [--seeds test|selection]
                                        [--out results/benchmarks/failure_memory.json] [--resume]

Same policy, same seeds, side by side: trial success (95 % CI), completion, grasp success and action
efficiency.  Without the memory a greedy policy in an unchanged scene repeats the action that just failed.
``--seeds test`` (default) plays the run's final-test seeds (``eval_seed + TEST_SEED_OFFSET`` ...), the figures
to quote; ``--seeds selection`` plays the selection seeds (``eval_seed + SELECTION_SEED_OFFSET`` ...), the ones
to decide on whether a policy should run with the memory.
"""

from __future__ import annotations

import argparse
import sys
from functools import partial
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))
import panda_grasp_env  # noqa: E402, F401  (first: it chooses MUJOCO_GL before mujoco is imported)

# isort: split

from benchmarks._common import (
    POLICY_COLUMNS,
    Results,
    check_selection_episodes,
    policy_figures,
    policy_row,
    shipped_checkpoints,
)
from panda_grasp_env.agents.learning.config import SELECTION_SEED_OFFSET, TEST_SEED_OFFSET
from panda_grasp_env.agents.learning.training import evaluate_policy
from panda_grasp_env.agents.policies.learned import Checkpoint

SEED_OFFSETS = {"test": TEST_SEED_OFFSET, "selection": SELECTION_SEED_OFFSET}


def measure(name: str, episodes: int | None, avoid_failures: bool, seed_offset: int) -> dict:
    checkpoint = Checkpoint(name)
    config = checkpoint.config
    metrics = evaluate_policy(
        checkpoint.load_policy(),
        config,
        episodes or config.final_eval_episodes,
        first_seed=config.eval_seed + seed_offset,
        acting=checkpoint.acting | {"avoid_failures": avoid_failures},
    )
    return policy_figures(metrics)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--checkpoints", default=None, help="comma-separated names (default: every heightmap one)")
    parser.add_argument("--episodes", type=int, default=None, help="default: each run's final_eval_episodes")
    parser.add_argument("--seeds", choices=sorted(SEED_OFFSETS), default="test")
    parser.add_argument("--out", type=Path, default=Path("results/benchmarks/failure_memory.json"))
    parser.add_argument("--resume", action="store_true", help="keep the sections already in --out")
    args = parser.parse_args()
    if args.seeds == "selection" and args.episodes is not None:
        check_selection_episodes(parser, args.episodes)
    names = args.checkpoints.split(",") if args.checkpoints else shipped_checkpoints(heightmap=True)
    for name in names:
        Checkpoint(name)  # unknown names fail before anything runs
    results = Results(args.out, args.resume)
    print(f"{'checkpoint':<20} {'memory':<7} {POLICY_COLUMNS}")
    for name in names:
        for avoid in (False, True):
            section = f"{name}/{args.seeds}/{'memory' if avoid else 'none'}"
            row = results.section(section, partial(measure, name, args.episodes, avoid, SEED_OFFSETS[args.seeds]))
            print(f"{name:<20} {'on' if avoid else 'off':<7} {policy_row(row)}")


if __name__ == "__main__":
    main()
