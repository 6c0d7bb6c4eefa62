"""Main job.  For now: the simulation-core demo -- an oracle builds a 4-block tower
from scattered blocks with grasp and place primitives, then pushes it over --
recorded as an MP4 from the front camera.

    MUJOCO_GL=egl python evaluate.py [--seed 0] [--out results/demo]

(The agent-vs-agent benchmark replaces this once the environments, planned and
learned agents exist.)
"""

from __future__ import annotations

import argparse
import json
import os
import sys
import time
from pathlib import Path

os.environ.setdefault("MUJOCO_GL", "egl")

import numpy as np  # noqa: E402

from agents.oracle_tower import build_tower, push_tower  # noqa: E402
from panda_grasp_env.stacking import blocks_displaced, tower_footprint_centre  # noqa: E402
from panda_grasp_env.video import VideoRecorder  # noqa: E402
from panda_grasp_env.workcell import Workcell  # noqa: E402


def parse_args(argv: list[str] | None = None) -> argparse.Namespace:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--seed", type=int, default=0, help="seed of the block layout")
    parser.add_argument("--out", type=Path, default=Path("results/demo"), help="output folder")
    parser.add_argument("--push", default="+y", choices=["+x", "+y", "-x", "-y"], help="push direction")
    parser.add_argument("--no-video", action="store_true", help="skip the MP4 (much faster)")
    return parser.parse_args(argv)


def main(argv: list[str] | None = None) -> int:
    args = parse_args(argv)
    args.out.mkdir(parents=True, exist_ok=True)
    cell = Workcell()
    cell.reset(np.random.default_rng(args.seed), "scattered")
    recorder = None if args.no_video else VideoRecorder(cell, camera="front", width=640, height=480)
    start = time.perf_counter()
    try:
        if recorder:
            recorder.caption = "build: oracle grasp + place"
        build = build_tower(cell)
        for step in build.steps:
            print(f"  {step.primitive:6s} {step.object or '':13s} {step.reason:12s} {step.sim_time:5.2f} s simulated")
        print(f"tower built: {build.success} (max yaw error {build.max_yaw_error_deg:.2f} deg)")
        centre = tower_footprint_centre(cell.block_positions())
        if recorder:
            recorder.caption = f"break: push {args.push}"
        push_result = push_tower(cell, args.push)
        cell.wait(1.5)
        displaced = blocks_displaced(cell.block_positions(), centre, cell.config.block_size)
        print(f"push {args.push}: {push_result.reason}, {displaced} blocks displaced")
    finally:
        if recorder:
            video = recorder.save(args.out / "demo.mp4")
            print(f"video: {video} ({recorder.frames_written} frames)")
    summary = {
        "seed": args.seed,
        "tower_built": build.success,
        "max_yaw_error_deg": build.max_yaw_error_deg,
        "primitives": [{"primitive": s.primitive, "reason": s.reason, "object": s.object} for s in build.steps],
        "push": {"direction": args.push, "reason": push_result.reason, "blocks_displaced": displaced},
        "simulated_s": cell.sim_time,
        "wall_s": time.perf_counter() - start,
    }
    tmp = args.out / "summary.json.tmp"
    tmp.write_text(json.dumps(summary, indent=2))
    tmp.replace(args.out / "summary.json")
    print(f"simulated {cell.sim_time:.1f} s in {summary['wall_s']:.1f} s wall; summary: {args.out / 'summary.json'}")
    return 0 if build.success and displaced >= 2 else 1


if __name__ == "__main__":
    sys.exit(main())
