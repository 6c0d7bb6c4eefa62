"""The shipped tower builder with and without ``FaceCentring``, and a random choice acting by the same rules.

    python benchmarks/face_centring.py [--episodes 50] [--seed-start 1400000]
                                       [--out results/benchmarks/face_centring.json] [--resume]

Same seeds, three agents on ``tower_build_dqn``'s env (TowerBuild, 4 blocks):

* ``memory``: the policy with its ``FailureMemory`` only (as shipped before ``FaceCentring``);
* ``shipped``: as shipped (``FailureMemory`` and ``FaceCentring``);
* ``random``: the policy's masks and both rules, but a uniformly random allowed action instead of its best --
  what the rules build without the policy's choice of block, heading and tower.

The default seeds are selection seeds (1400000...), on which the rule was chosen; the held-out figures are on
the card (``train.py --retest``) and in docs/tall-towers.md.
"""

from __future__ import annotations

import argparse
import sys
from functools import partial
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))
import panda_grasp_env  # noqa: E402, F401  (first: it chooses MUJOCO_GL before mujoco is imported)

# isort: split


from benchmarks._common import POLICY_COLUMNS, RandomChoice, Results, policy_figures, policy_row
from panda_grasp_env.agents.learning.training import evaluate_policy
from panda_grasp_env.agents.policies.learned import Checkpoint

AGENTS = ("memory", "shipped", "random")


def measure(agent: str, episodes: int, first_seed: int) -> dict:
    checkpoint = Checkpoint("tower_build_dqn")
    config = checkpoint.config
    policy = checkpoint.load_policy()
    acting = checkpoint.acting | ({"centre_on_faces": False} if agent == "memory" else {})
    model = RandomChoice(policy, first_seed) if agent == "random" else policy
    return policy_figures(evaluate_policy(model, config, episodes, first_seed=first_seed, acting=acting))


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--episodes", type=int, default=50)
    parser.add_argument("--seed-start", type=int, default=1_400_000, help="default: selection seeds")
    parser.add_argument("--out", type=Path, default=Path("results/benchmarks/face_centring.json"))
    parser.add_argument("--resume", action="store_true", help="keep the sections already in --out")
    args = parser.parse_args()
    if args.episodes < 1:
        parser.error(f"--episodes must be >= 1, got {args.episodes}")
    results = Results(args.out, args.resume)
    print(f"{'agent':<8} {POLICY_COLUMNS}")
    for agent in AGENTS:
        section = f"{agent}/{args.seed_start}/{args.episodes}"
        row = results.section(section, partial(measure, agent, args.episodes, args.seed_start))
        print(f"{agent:<8} {policy_row(row)}")


if __name__ == "__main__":
    main()
