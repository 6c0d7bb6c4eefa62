"""How long a 10-block structure episode takes: a 4-3-2-1 pyramid of cubes built by ``planned_lookahead``.

    python benchmarks/structure_episode_time.py [--seeds 5] [--seed-start 0]

Each episode runs as ``evaluate.py`` runs it (``run_episode``: the env made, reset, played to its end,
one worker), one after another on this machine; prints each episode's wall seconds, success and actions,
then the median wall time.
"""

from __future__ import annotations

import argparse
import statistics
import sys
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))
import panda_grasp_env  # noqa: E402, F401  (first: it chooses MUJOCO_GL before mujoco is imported)

# isort: split

import panda_grasp_env.agents.policies.structures  # noqa: F401  (registers planned_lookahead)
from panda_grasp_env.agents.evaluation.episodes import close_kept_env, run_episode
from panda_grasp_env.agents.evaluation.protocol import EpisodeSpec
from panda_grasp_env.model.structure_suite import cube
from panda_grasp_env.model.structures import Structure

#: Ten cubes: four in a row, three on their joints, two, one.
PYRAMID_10 = Structure(
    "pyramid_10",
    tuple(cube((k - (n - 1) / 2) * 0.055, 0.0, 4 - n) for n in (4, 3, 2, 1) for k in range(n)),
    description="a 4-3-2-1 pyramid of ten cubes",
)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--seeds", type=int, default=5)
    parser.add_argument("--seed-start", type=int, default=0)
    args = parser.parse_args()
    walls = []
    print(f"{PYRAMID_10.description}: planned_lookahead, one worker")
    for seed in range(args.seed_start, args.seed_start + args.seeds):
        spec = EpisodeSpec("planned_lookahead", "Structure", seed, (("structure", PYRAMID_10.to_dict()),))
        record = run_episode(spec)
        result, wall = record["result"], record["timing"]["wall_seconds"]
        walls.append(wall)
        print(f"seed {seed}: {wall:6.1f} s  success {result['success']}  actions {result['actions']}")
    close_kept_env()
    print(f"median wall time per episode: {statistics.median(walls):.1f} s over {len(walls)} episodes")


if __name__ == "__main__":
    main()
