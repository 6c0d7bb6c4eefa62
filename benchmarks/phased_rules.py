"""Do the phased agent's rules cycle by themselves?  ``build_and_break_dqn`` against a random choice acting by them.

    python benchmarks/phased_rules.py [--seeds 1400000,1400001] [--actions 300]
                                      [--out results/benchmarks/phased_rules.json] [--resume]

Both play BuildAndBreak in the phased agent's env (its wider heightmap) through ``PhasedAgent``, with every
rule it acts by: the builder's ``FailureMemory`` and ``FaceCentring``, the breaker's ``InwardPushes``, and the
knock-down of a stuck build (``unstuck_by``).  ``random`` replaces each part's choice with a seeded uniformly
random action among those its policy allows (``RandomChoice``).  Prints cycles and cycles per simulated hour
per seed.  The default seeds are selection seeds, on which the rules were chosen; the held-out figures are
in docs/tall-towers.md.
"""

from __future__ import annotations

import argparse
import sys
from functools import partial
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))
import panda_grasp_env  # noqa: E402, F401  (first: it chooses MUJOCO_GL before mujoco is imported)

# isort: split

import torch as th

from benchmarks._common import RandomChoice, Results
from panda_grasp_env.agents.evaluation.protocol import phased_env
from panda_grasp_env.agents.policies.phased import PhasedAgent

AGENTS = ("shipped", "random")


def measure(agent: str, seed: int, actions: int) -> dict:
    """Cycles, builds and simulated seconds of one BuildAndBreak episode of ``actions`` actions."""
    env = phased_env("build_and_break_dqn", "BuildAndBreak", max_episode_steps=actions)
    try:
        player = PhasedAgent("build_and_break_dqn", env)
        if agent == "random":
            for part in player.agents.values():
                part.policy = RandomChoice(part.policy, seed)
        observation, info = env.reset(seed=seed)
        player.reset(observation, info)
        taken, terminated, truncated = 0, False, False
        while not (terminated or truncated or taken == actions):
            observation, _, terminated, truncated, info = env.step(player.act(observation, info))
            taken += 1
        return {
            "actions": taken,
            "cycles": int(info["cycles"]),
            "builds": int(info["builds"]),
            "sim_seconds": round(float(info["sim_time"]), 2),
            "terminated": bool(terminated),
        }
    finally:
        env.close()


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--seeds", default="1400000,1400001", help="comma-separated; default: selection seeds")
    parser.add_argument("--actions", type=int, default=300)
    parser.add_argument("--out", type=Path, default=Path("results/benchmarks/phased_rules.json"))
    parser.add_argument("--resume", action="store_true", help="keep the sections already in --out")
    args = parser.parse_args()
    if args.actions < 1:
        parser.error(f"--actions must be >= 1, got {args.actions}")
    seeds = [int(seed) for seed in args.seeds.split(",")]
    th.set_num_threads(1)
    results = Results(args.out, args.resume)
    print(f"{'agent':<8} {'seed':>8} {'actions':>7} {'builds':>6} {'cycles':>6} {'cycles / sim h':>14}")
    for agent in AGENTS:
        for seed in seeds:
            row = results.section(f"{agent}/{seed}/{args.actions}", partial(measure, agent, seed, args.actions))
            rate = row["cycles"] / (row["sim_seconds"] / 3600)
            print(f"{agent:<8} {seed:>8} {row['actions']:>7} {row['builds']:>6} {row['cycles']:>6} {rate:>14.1f}")


if __name__ == "__main__":
    main()
