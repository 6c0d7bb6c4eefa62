"""Where does the goal-conditioned builder lose its structures?  Plays a ``goal_heightmap_dqn`` run's best
validated policy (``best_policy``) on generated structures and sorts every action by what it did to the goal.

    python benchmarks/builder_failures.py runs/<run> [--episodes 12] [--seeds validation|selection]
                                          [--avoid-failures] [--place-where-lacking]

It plays the run's validation seeds (``eval_seed`` ...) or its selection seeds (``eval_seed +
SELECTION_SEED_OFFSET`` ...), never its test seeds.  ``--avoid-failures``: the agent keeps its
``FailureMemory`` (``PolicyAgent``'s ``avoid_failures``), and ``--place-where-lacking``: it places only where
the goal heightmap stands above the scene's (``LackingPlaces``): acting rules chosen on the selection seeds.

Each action is one of:

* ``grasp_took_built``: a grasp that lowered the count of targets a piece stands in (it lifted a built piece);
* ``grasp_ok`` / ``grasp_failed``: any other grasp, by the primitive's own outcome;
* ``place_filled``: a place that raised the count;
* ``place_knocked``: a place that lowered it (the load or the fingers moved a built piece);
* ``place_off``: a place whose primitive succeeded and that changed nothing;
* ``place_failed_<reason>``: the primitive itself failed (``placed_off``: the piece came to rest off its aim).

For every place that changed nothing it prints where the piece came to rest against the nearest target of its
kind (``landing_error``) and, in the summary, the misses per kind of piece, how many were left tilted past
the task's 10 degrees, and the quartiles of each miss.

Prints one JSON line per episode and a summary line.  Reading it: collapses that ``grasp_took_built`` explains
want a different action prior or reward; misses of a few millimetres want a finer place head; misses of a
block's height want a better choice of target.
"""

from __future__ import annotations

import argparse
import json
import sys
from collections import Counter
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))
import panda_grasp_env  # noqa: E402, F401  (first: it chooses MUJOCO_GL before mujoco is imported)

# isort: split

import numpy as np

from panda_grasp_env.agents.learning.config import (
    SELECTION_SEED_OFFSET,
    load_config,
    make_env,
    observation_transform,
)
from panda_grasp_env.agents.learning.records import load_best_policy
from panda_grasp_env.agents.policies.policy_agent import PolicyAgent
from panda_grasp_env.model.structures import symmetry
from panda_grasp_env.tasks.structure_build import GOAL_FIELDS, TURN_TOLERANCE, heading_misses, read_rows


def landing_error(observation: dict, slot: int) -> dict[str, float]:
    """Where the piece in object ``slot`` came to rest against the nearest target of its kind (3-D distance):
    its kind, the horizontal and vertical misses (metres), the heading's miss (radians, modulo the kind's
    symmetry) and the tilt from upright (radians)."""
    pieces = np.asarray(observation["achieved_goal"], dtype=float).reshape(-1, GOAL_FIELDS)
    goal = np.asarray(observation["desired_goal"], dtype=float).reshape(-1, GOAL_FIELDS)
    piece = pieces[slot]
    targets = goal[np.round(goal[:, 6]) == np.round(piece[6])]
    nearest = targets[np.argmin(np.linalg.norm(targets[:, :3] - piece[:3], axis=1))]
    kind = read_rows(piece[None])[0][0]
    return {
        "piece": kind,
        "xy": float(np.hypot(*(piece[:2] - nearest[:2]))),
        "z": float(piece[2] - nearest[2]),
        "heading": float(heading_misses(nearest[None], piece[None], 2 * np.pi / symmetry(kind))[0, 0]),
        "tilt": float(piece[5]),
    }


def play(env, agent: PolicyAgent, seed: int) -> dict:
    """One episode's actions sorted as the module doc says, with where each place that filled nothing left its
    piece (``landing_error``)."""
    observation, info = env.reset(seed=seed)
    agent.reset(observation, info)
    n_targets, tier = int(info["n_targets"]), int(info["tier"])
    kinds: Counter[str] = Counter()
    misses = []
    in_place = 0
    while True:
        action = agent.act(observation, info)
        observation, _, terminated, truncated, info = env.step(action)
        now = int(info["in_place"])
        primitive = info["primitive"]
        if primitive == "grasp":
            kind = (
                "grasp_took_built" if now < in_place else ("grasp_ok" if info["primitive_success"] else "grasp_failed")
            )
        elif now < in_place:
            kind = "place_knocked"
        elif now > in_place:
            kind = "place_filled"
        else:
            kind = "place_off" if info["primitive_success"] else f"place_failed_{info['primitive_reason']}"
            slot = info["primitive_object"]
            if slot.startswith("object_"):
                misses.append({"kind": kind, **landing_error(observation, int(slot[7:]))})
        kinds[kind] += 1
        in_place = now
        if terminated or truncated:
            break
    return {
        "seed": seed,
        "tier": tier,
        "success": bool(info["is_success"]),
        "failure": info.get("failure_reason"),
        "placed": f"{in_place}/{n_targets}",
        "actions": dict(sorted(kinds.items())),
        "misses": misses,
    }


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("run", type=Path, help="a goal_heightmap_dqn run folder")
    parser.add_argument("--episodes", type=int, default=12)
    parser.add_argument("--seeds", choices=("validation", "selection"), default="validation")
    parser.add_argument("--avoid-failures", action="store_true")
    parser.add_argument("--place-where-lacking", action="store_true")
    args = parser.parse_args()
    if args.episodes < 1:
        raise ValueError(f"--episodes must be at least 1, got {args.episodes}")
    config = load_config(args.run / "config.yaml")
    policy, best = load_best_policy(args.run)
    env = make_env(config)
    first_seed = config.eval_seed + (SELECTION_SEED_OFFSET if args.seeds == "selection" else 0)
    agent = PolicyAgent(
        policy,
        observation_transform(config),
        config.name,
        avoid_failures=args.avoid_failures,
        place_where_lacking=args.place_where_lacking,
    )
    totals: Counter[str] = Counter()
    misses, wins = [], 0
    for i in range(args.episodes):
        episode = play(env, agent, first_seed + i)
        print(json.dumps(episode), flush=True)
        totals.update(episode["actions"])
        misses += episode["misses"]
        wins += episode["success"]
    env.close()
    summary = {
        "run": str(args.run),
        "best_steps": best["steps"],
        "avoid_failures": args.avoid_failures,
        "place_where_lacking": args.place_where_lacking,
        "seeds": [first_seed, first_seed + args.episodes - 1],
        "success": f"{wins}/{args.episodes}",
        "actions": dict(sorted(totals.items())),
        "misses": dict(sorted(Counter(m["piece"] for m in misses).items())),
        "tipped_over": int(sum(abs(m["tilt"]) > TURN_TOLERANCE for m in misses)),
        **{
            f"miss_{key}_quartiles": np.percentile([abs(m[key]) for m in misses], [25, 50, 75]).round(4).tolist()
            for key in ("xy", "z", "heading", "tilt")
            if misses
        },
    }
    print(json.dumps(summary), flush=True)


if __name__ == "__main__":
    main()
