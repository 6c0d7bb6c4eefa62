"""Honest transit: seeded random primitive actions, and what they touch and move besides their work.

    python benchmarks/transit_collateral.py [--actions 250] [--resume]

For each scene (TowerBuild, TowerBreak, BuildAndBreak, GraspClutter: ids with
their default ``primitive`` action mode) it runs ``--actions`` random actions
(episode e: ``reset(seed=SEED_BASE + e)``, the ``RandomAgent`` seeded with ``SEED_BASE + e``)
and prints, from each step's ``info``:

* the share of actions with ``transit_contacts == 0`` (the robot and its load
  touched no object outside the work segment) and with ``transit_disturbed == 0``
  (no object at rest moved or tipped during transit) -- goal >= 99.5 % each;
* collateral: objects other than the targets moved (> 1 cm) or tipped, per
  action, by primitive -- the agent's choice, reported, not a transit failure;
* simulated seconds per executed primitive (median; instant refusals such as
  ``out_of_workspace`` left out), and the random agent's episode success.

Results go to one JSON file, saved atomically after each scene; ``--resume``
skips finished scenes.
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
import numpy as np

from benchmarks._common import Results, rate
from panda_grasp_env.agents.policies.random_agent import RandomAgent

SCENES = ("PandaTowerBuild-v0", "PandaTowerBreak-v0", "PandaBuildAndBreak-v0", "PandaGraspClutter-v0")
#: Episode seeds start here (apart from the evaluation and training seeds).
SEED_BASE = 700_000


def random_primitives(env_id: str, actions: int) -> dict:
    env = gym.make(f"panda_grasp_env:{env_id}")
    steps: list[dict] = []
    episodes = successes = 0
    done = True
    while len(steps) < actions:
        if done:
            agent = RandomAgent(env.action_space, seed=SEED_BASE + episodes)
            observation, info = env.reset(seed=SEED_BASE + episodes)
            agent.reset(observation, info)
            episodes += 1
        observation, _, terminated, truncated, info = env.step(agent.act(observation, info))
        done = terminated or truncated
        successes += bool(done and info["is_success"])
        steps.append(
            {
                key: info[key]
                for key in (
                    "primitive",
                    "primitive_reason",
                    "primitive_sim_time",
                    "transit_contacts",
                    "transit_disturbed",
                    "disturbed",
                )
            }
        )
    env.close()
    n = len(steps)
    by_primitive: dict[str, list[dict]] = {}
    for step in steps:
        by_primitive.setdefault(step["primitive"], []).append(step)
    executed = [s["primitive_sim_time"] for s in steps if s["primitive_sim_time"] > 0]
    return {
        "actions": n,
        "transit_contacts_zero": rate(sum(s["transit_contacts"] == 0 for s in steps), n),
        "transit_disturbed_zero": rate(sum(s["transit_disturbed"] == 0 for s in steps), n),
        "collateral_per_action": {
            p: round(float(np.mean([s["disturbed"] for s in group])), 4) for p, group in sorted(by_primitive.items())
        },
        "sim_seconds_median": {
            p: round(
                float(np.median([s["primitive_sim_time"] for s in group if s["primitive_sim_time"] > 0] or [0])), 3
            )
            for p, group in sorted(by_primitive.items())
        },
        "sim_seconds_median_executed": round(float(np.median(executed)), 3) if executed else 0.0,
        "reasons": dict(sorted(Counter(f"{s['primitive']}:{s['primitive_reason']}" for s in steps).items())),
        "random_episodes": rate(successes, episodes),
    }


def _percent(r: dict) -> str:
    return f"{100 * r['rate']:.1f} % ({r['successes']}/{r['n']}, 95 % CI {100 * r['ci95'][0]:.1f}-{100 * r['ci95'][1]:.1f})"


def main(argv: list[str] | None = None) -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--actions", type=int, default=250, help="random actions per scene")
    parser.add_argument("--out", type=Path, default=Path("results/benchmarks/transit_collateral.json"))
    parser.add_argument("--resume", action="store_true", help="keep scenes already in --out")
    args = parser.parse_args(argv)
    if args.actions < 1:
        parser.error("--actions must be positive")
    results = Results(args.out, args.resume)
    totals = Counter()
    for env_id in SCENES:
        r = results.section(env_id, lambda env_id=env_id: random_primitives(env_id, args.actions))
        totals["n"] += r["actions"]
        totals["contacts"] += r["transit_contacts_zero"]["successes"]
        totals["disturbed"] += r["transit_disturbed_zero"]["successes"]
        print(f"{env_id}: {r['actions']} random actions")
        print(f"  transit_contacts == 0:  {_percent(r['transit_contacts_zero'])}")
        print(f"  transit_disturbed == 0: {_percent(r['transit_disturbed_zero'])}")
        print(f"  collateral (objects disturbed per action): {r['collateral_per_action']}")
        print(
            f"  simulated s per executed primitive (median): {r['sim_seconds_median']}, "
            f"all {r['sim_seconds_median_executed']}"
        )
        print(f"  reasons: {r['reasons']}")
        print(f"  random agent's episodes: {_percent(r['random_episodes'])} successful")
    print(
        f"all scenes, {totals['n']} actions: transit_contacts == 0 {_percent(rate(totals['contacts'], totals['n']))}; "
        f"transit_disturbed == 0 {_percent(rate(totals['disturbed'], totals['n']))}   (goal >= 99.5 % each)"
    )
    print(f"saved {args.out}")


if __name__ == "__main__":
    main()
