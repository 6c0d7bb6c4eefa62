"""Wall time per primitive against the physics it runs, per task, in one run.

    python benchmarks/primitive_overhead.py [--primitives 25] [--repeats 3]
                                            [--tasks TowerBuild,TowerBreak,GraspClutter,GraspMeshClutter,...]
                                            [--out results/benchmarks/primitive_overhead.json] [--resume]

For each task: ``--primitives`` seeded random primitive actions through ``gymnasium.make`` (``action_space``
seeded with 0, env seeds 0, 1, ... as episodes end).  Per primitive that ran physics (a rejected action
runs none and is left out), the wall time, the ``mj_step`` calls it made and the wall time inside them
(a wrapper around ``mujoco.mj_step`` counts both), and the simulated time it took.  Then the raw
``mj_step`` rate of the task's scene from its reset state, controls held.  Printed per task (medians
over primitives, then the median over ``--repeats`` runs in fresh processes, tasks alternating):

* wall per primitive, physics steps per primitive, simulated seconds per wall second;
* ``wall / (steps / raw rate)``: the issue's overhead figure (goal <= 1.25); the raw rate is taken at
  rest, so it also charges the primitive for contacts that make physics in motion dearer;
* ``wall / time in mj_step``: the same ratio over the very states the primitive visited (Python only).
"""

from __future__ import annotations

import argparse
import json
import statistics
import subprocess
import sys
import time
from pathlib import Path
from typing import Any

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))  # benchmarks._physics, also in the workers
_MESH_HEAP = {"objects": [{"shape": "mesh", "split": "test"}]}
#: Row -> (task, ``make`` options; ``sleep`` sets ``SceneConfig.sleep``).  The mesh heap drops 10 test objects
#: (the objects extra); its ``Awake`` row turns off the island sleeping mesh scenes have by default.
ROWS: dict[str, tuple[str, dict[str, Any]]] = {
    "TowerBuild": ("TowerBuild", {}),
    "TowerBreak": ("TowerBreak", {}),
    "GraspClutter": ("GraspClutter", {}),
    "GraspMeshClutter": ("GraspMeshClutter", _MESH_HEAP),
    "GraspMeshClutterAwake": ("GraspMeshClutter", {**_MESH_HEAP, "sleep": False}),
}
TASKS = tuple(ROWS)
RAW_STEPS = 5000


def measure(row: str, primitives: int) -> dict[str, float]:
    """One row of ``ROWS`` in this interpreter (see the module docstring)."""
    import gymnasium as gym
    import numpy as np

    import panda_grasp_env  # noqa: F401  (it chooses MUJOCO_GL before mujoco is imported)
    from benchmarks._physics import raw_step_rate, timed_mj_step
    from panda_grasp_env.model.scene import SceneConfig

    task, options = ROWS[row]
    options = dict(options)
    if "sleep" in options:
        options["scene"] = SceneConfig(sleep=options.pop("sleep"))
    env = gym.make(f"panda_grasp_env:Panda{task}-v0", **options)
    env.action_space.seed(0)
    seed = 0
    env.reset(seed=seed)
    rows = []
    with timed_mj_step() as physics:
        for _ in range(primitives):
            physics.seconds, physics.steps = 0.0, 0
            start = time.perf_counter()
            _, _, terminated, truncated, info = env.step(env.action_space.sample())
            wall = time.perf_counter() - start
            if physics.steps:
                rows.append((wall, physics.seconds, physics.steps, info.get("primitive_sim_time", 0.0)))
            if terminated or truncated:
                seed += 1
                env.reset(seed=seed)
    cell = env.unwrapped.cell
    env.reset(seed=0)
    raw = raw_step_rate(cell.model, cell.data, RAW_STEPS)
    env.close()
    walls, inside, steps, sim = (np.array(column) for column in zip(*rows))
    return {
        "primitives_with_physics": len(rows),
        "wall_s": float(np.median(walls)),
        "steps": float(np.median(steps)),
        "raw_rate": raw,
        "sim_per_wall": float(sim.sum() / walls.sum()),
        "wall_over_raw": float(np.median(walls / (steps / raw))),
        "wall_over_inside": float(np.median(walls / inside)),
    }


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--primitives", type=int, default=25)
    parser.add_argument("--repeats", type=int, default=3)
    parser.add_argument("--tasks", default=",".join(TASKS))
    parser.add_argument("--out", type=Path, default=ROOT / "results" / "benchmarks" / "primitive_overhead.json")
    parser.add_argument("--resume", action="store_true", help="keep repeats already saved in --out")
    parser.add_argument("--worker", choices=TASKS, help=argparse.SUPPRESS)
    args = parser.parse_args()
    if args.primitives < 1 or args.repeats < 1:
        raise ValueError(f"--primitives and --repeats must be >= 1, got {args.primitives}, {args.repeats}")
    if args.worker:
        print(json.dumps(measure(args.worker, args.primitives)))
        return
    tasks = args.tasks.split(",")
    unknown = sorted(set(tasks) - set(TASKS))
    if unknown:
        raise ValueError(f"unknown --tasks {unknown}; choose from {list(TASKS)}")

    from benchmarks._common import Results

    def run(task: str) -> dict[str, float]:
        command = [sys.executable, __file__, "--worker", task, "--primitives", str(args.primitives)]
        out = subprocess.run(command, check=True, capture_output=True, text=True, cwd=ROOT)
        return json.loads(out.stdout.strip().splitlines()[-1])

    results = Results(args.out, args.resume)
    repeats = [results.section(f"repeat_{r}", lambda: {task: run(task) for task in tasks}) for r in range(args.repeats)]
    print(f"medians: {args.primitives} random primitives per task, {args.repeats} repeats ({results.data['machine']})")
    print(
        f"{'task':21s} {'wall/prim s':>11s} {'steps':>6s} {'raw/s':>7s} {'sim s/wall s':>12s} "
        f"{'wall/(steps/raw)':>16s} {'wall/in mj_step':>15s}"
    )
    summary = {}
    for task in tasks:
        figures = {key: statistics.median(r[task][key] for r in repeats) for key in repeats[0][task]}
        summary[task] = figures
        print(
            f"{task:21s} {figures['wall_s']:11.3f} {figures['steps']:6.0f} {figures['raw_rate']:7.0f} "
            f"{figures['sim_per_wall']:12.2f} {figures['wall_over_raw']:16.2f} {figures['wall_over_inside']:15.2f}"
        )
    print("goal (issue 29): wall/(steps/raw) <= 1.25")
    results.data.pop("summary", None)
    results.section("summary", lambda: summary)


if __name__ == "__main__":
    main()
