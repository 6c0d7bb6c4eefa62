"""OMPL planners on the same queries in a scene that discriminates: the source study's table redone.

    python benchmarks/planner_comparison.py [--repeats 2] [--time-limit 3] [--out results/benchmarks/planners.json] [--resume]

Scene: a shelf cubby on the table (board at 26-28 cm, side walls 38 cm apart, a
back wall) in front of the robot.  Queries: from home to five grasp
configurations inside the cubby (approach horizontal, facing away from the
robot, at y = -6 ... 6 cm), each solved ``--repeats`` times per planner within
``--time-limit`` seconds (anytime planners use all of it).  Figures per planner:
success rate, median planning time (including path simplification), median
joint-space path length, collision checks.  One thread.
"""

from __future__ import annotations

import argparse
import os
import statistics
import sys
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))
for _threads in ("OMP_NUM_THREADS", "OPENBLAS_NUM_THREADS", "MKL_NUM_THREADS"):
    os.environ.setdefault(_threads, "1")

import numpy as np

from benchmarks._common import Results, rate
from panda_grasp_env.control.ik import PoseIK, ToleranceSampler
from panda_grasp_env.control.planning import PLANNERS, Box, MotionPlanner
from panda_grasp_env.geometry import rotation_about, top_down_rotation
from panda_grasp_env.model.robot import HOME_QPOS

SHELF = (
    Box((0.66, 0.0, 0.27), (0.15, 0.2, 0.01)),
    Box((0.66, -0.19, 0.135), (0.15, 0.01, 0.135)),
    Box((0.66, 0.19, 0.135), (0.15, 0.01, 0.135)),
    Box((0.82, 0.0, 0.135), (0.01, 0.2, 0.135)),
)


def goals(planner: MotionPlanner) -> list[np.ndarray]:
    ik, rng = PoseIK(), np.random.default_rng(0)
    rotation = rotation_about([0.0, 1.0, 0.0], -np.pi / 2) @ top_down_rotation(np.pi / 2)
    found = []
    for y in (-0.06, -0.03, 0.0, 0.03, 0.06):
        result, _ = ToleranceSampler().solve(ik, np.array([0.62, y, 0.12]), rotation, HOME_QPOS, rng)
        if result is not None and planner.is_valid(result.qpos):
            found.append(result.qpos)
    return found


def compare(name: str, repeats: int, time_limit: float) -> dict:
    planner = MotionPlanner(obstacles=SHELF, planner=name, seed=0)
    queries = goals(planner) * repeats
    checks_before = planner.checks
    results = [planner.plan(HOME_QPOS, goal, time_limit) for goal in queries]
    solved = [r for r in results if r.success]
    return rate(len(solved), len(results)) | {
        "seconds_median": statistics.median(r.seconds for r in results),
        "path_length_median": statistics.median(r.length for r in solved) if solved else None,
        "collision_checks_per_query": (planner.checks - checks_before) / len(results),
    }


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--repeats", type=int, default=2)
    parser.add_argument("--time-limit", type=float, default=3.0)
    parser.add_argument("--out", type=Path, default=Path("results/benchmarks/planners.json"))
    parser.add_argument("--resume", action="store_true")
    args = parser.parse_args()
    results = Results(args.out, args.resume)
    print(f"{'planner':11s} {'solved':>22s} {'time (median)':>14s} {'path length':>12s} {'checks/query':>13s}")
    for name in PLANNERS:
        r = results.section(name, lambda name=name: compare(name, args.repeats, args.time_limit))
        length = "-" if r["path_length_median"] is None else f"{r['path_length_median']:.2f} rad"
        print(
            f"{name:11s} {100 * r['rate']:5.1f} % ({r['successes']:2d}/{r['n']}) CI {100 * r['ci95'][0]:3.0f}-"
            f"{100 * r['ci95'][1]:3.0f} % {r['seconds_median']:11.3f} s {length:>12s} {r['collision_checks_per_query']:13.0f}"
        )
    print("    (source study: RRTConnect 100 % in 0.39 s; BKPIECE 95 % in 1.24 s; PRM 100 % in 7.77 s; SBL 40 %)")
    print(f"saved {args.out}")


if __name__ == "__main__":
    main()
