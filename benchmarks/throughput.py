"""Simulation and rendering throughput of the workcell, printed side by side in one run.

    python benchmarks/throughput.py [--repeats 5] [--out results/benchmarks/throughput.json] [--resume]

* raw ``mj_step`` rate of the scene (tower standing, arm at home);
* controller-level rate: physics steps per second while the Cartesian
  controller (mink IK every 20 physics steps = 25 Hz) drives the arm, and its
  ratio to the raw rate (goal >= 0.70);
* primitives per second (grasp + place pairs on scattered blocks);
* rendering frames per second in the fast profile for 84x84 and 640x480 RGB,
  depth and segmentation from the overhead camera (and RGB in the pretty profile).

Every figure is the median of ``--repeats`` runs.
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))
import panda_grasp_env  # noqa: E402, F401  (first: it chooses MUJOCO_GL before mujoco is imported)

# isort: split

import mujoco  # noqa: E402
import numpy as np  # noqa: E402

from benchmarks._common import Results, median_rate  # noqa: E402
from panda_grasp_env.primitives.top_down import grasp, place  # noqa: E402
from panda_grasp_env.sim.rendering import CameraRenderer  # noqa: E402
from panda_grasp_env.sim.workcell import Workcell  # noqa: E402


def physics(cell: Workcell, repeats: int) -> dict[str, float]:
    cell.reset(np.random.default_rng(0), "tower")

    def raw() -> int:
        mujoco.mj_step(cell.model, cell.data, nstep=4000)
        return 4000

    raw_rate = median_rate(raw, repeats)
    targets = [np.array([0.45, 0.15, 0.3]), np.array([0.55, -0.15, 0.2])]

    def controlled() -> int:
        start = cell.physics.steps
        for i in range(100):
            if i % 25 == 0:
                cell.controller.set_goal(targets[(i // 25) % 2], -np.pi / 2)
            cell.physics.control_step(cell.controller)
        return cell.physics.steps - start

    cell.reset(np.random.default_rng(0), "tower")
    control_rate = median_rate(controlled, repeats)
    rng = np.random.default_rng(1)

    def primitives() -> int:
        cell.reset(rng, "scattered")
        positions, yaws = cell.block_positions(), cell.block_yaws()
        grasp(cell, *positions[1], float(yaws[1]))
        place(cell, positions[0][0], positions[0][1], 0.05, float(yaws[0]))
        return 2

    primitive_rate = median_rate(primitives, repeats)
    return {
        "raw_mj_step_per_s": raw_rate,
        "controlled_physics_steps_per_s": control_rate,
        "control_steps_per_s": control_rate / cell.physics.control_substeps,
        "controller_to_raw_ratio": control_rate / raw_rate,
        "primitives_per_s": primitive_rate,
    }


def rendering(cell: Workcell, repeats: int) -> dict[str, float]:
    cell.reset(np.random.default_rng(0), "tower")
    figures = {}
    for width, height in ((84, 84), (640, 480)):
        for profile, modalities in (("fast", ("rgb", "depth", "segmentation")), ("pretty", ("rgb",))):
            renderer = CameraRenderer(cell.model, width, height, profile)
            for modality in modalities:
                renderer.render(cell.data, "overhead", modality)  # warm up

                def frames(renderer=renderer, modality=modality) -> int:
                    for _ in range(30):
                        renderer.render(cell.data, "overhead", modality)
                    return 30

                figures[f"{profile}_{modality}_{width}x{height}_fps"] = median_rate(frames, repeats)
            renderer.close()
    return figures


def main(argv: list[str] | None = None) -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--repeats", type=int, default=5)
    parser.add_argument("--out", type=Path, default=Path("results/benchmarks/throughput.json"))
    parser.add_argument("--resume", action="store_true", help="keep sections already in --out")
    args = parser.parse_args(argv)
    results = Results(args.out, args.resume)
    cell = Workcell()
    sim = results.section("physics", lambda: physics(cell, args.repeats))
    print(f"raw mj_step:                 {sim['raw_mj_step_per_s']:9.0f} steps/s")
    print(
        f"controller-level physics:    {sim['controlled_physics_steps_per_s']:9.0f} steps/s "
        f"({sim['control_steps_per_s']:.0f} control steps/s at 25 Hz)"
    )
    print(f"controller / raw ratio:      {sim['controller_to_raw_ratio']:9.2f}   (goal >= 0.70)")
    print(f"primitives:                  {sim['primitives_per_s']:9.2f} per s")
    render = results.section("rendering", lambda: rendering(cell, args.repeats))
    for key, fps in render.items():
        print(f"render {key:32s} {fps:8.0f}")
    print(f"saved {args.out}")


if __name__ == "__main__":
    main()
