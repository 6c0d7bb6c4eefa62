"""Perception and planned grasping with domain randomisation off and on, over the same held-out scenes.

    python benchmarks/randomization.py [--scenes 200] [--grasp-scenes 200] [--resume]
                                       [--out results/benchmarks/randomization.json] [--grid docs/images/randomization.png]

The scenes are ``PandaTowerBuild-v0`` resets, seeds 60000 onwards. A task lays out the same scene with the
option on or off, so the two columns differ only by the randomisation (the defaults of
``panda_grasp_env.randomization.Randomization``). No development run used these seeds: scenes 30000-30003
and grasps 40000-40011 were used while writing it, and the depth-noise default was chosen on them.

* **Block position error**, mm: ``estimate_block_poses`` from the overhead and front RGB-D observations at
  640 x 480, read through the camera models the env publishes. The Kinect-like noise is added as the
  planned agents add it, on top of the env's depth noise when randomisation is on.
* **Colour segmentation IoU**: ``colour_masks`` on the overhead RGB against the segmentation observation,
  per block, averaged.
* **Planned grasp success on isolated cubes**: ``evaluate.py``'s planned agent on ``PandaGrasp-v0`` with
  ``shapes=("cube",)``, seeds 50000 onwards. The figure is the share of episodes whose first grasp held.

``--grid`` also writes a figure: the front camera on 8 randomised scenes.
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))
import panda_grasp_env  # noqa: E402, F401  (first: it chooses MUJOCO_GL before mujoco is imported)

# isort: split

import gymnasium as gym
import numpy as np

from benchmarks._common import Results, rate
from panda_grasp_env.agents.evaluation.episodes import make_agent, make_env, play_episode
from panda_grasp_env.agents.evaluation.protocol import EpisodeSpec
from panda_grasp_env.perception.noise import DepthNoise, RGBNoise
from panda_grasp_env.perception.pose import View, estimate_block_poses
from panda_grasp_env.perception.segmentation import colour_masks

SCENE_SEED, GRASP_SEED = 60_000, 50_000
CAMERAS = ("overhead", "front")


def perception(scenes: int, randomization: bool) -> dict:
    env = gym.make(
        "panda_grasp_env:PandaTowerBuild-v0",
        obs_mode="rgbd+segmentation",
        cameras=CAMERAS,
        image_size=(640, 480),
        randomization=randomization or None,
    )
    cell = env.unwrapped.cell
    errors_mm, ious, missed = [], [], 0
    for scene in range(scenes):
        observation, info = env.reset(seed=SCENE_SEED + scene)
        noise = np.random.default_rng(SCENE_SEED + scene)
        views = [
            View(
                RGBNoise().apply(observation[f"{c}_rgb"], noise),
                DepthNoise().apply(observation[f"{c}_depth"][..., 0], noise),
                info["camera_models"][c],
            )
            for c in CAMERAS
        ]
        poses = estimate_block_poses(views, info["block_colours"], info["block_size"])
        for index, name in enumerate(cell.block_names):
            if name in poses:
                errors_mm.append(1000 * float(np.linalg.norm(poses[name].position - cell.block_positions()[index])))
            else:
                missed += 1
        truth = observation["overhead_segmentation"][..., 0]
        for name, mask in colour_masks(views[0].rgb, info["block_colours"]).items():
            true_mask = truth == 2 + cell.block_names.index(name)
            union = np.count_nonzero(mask | true_mask)
            if union:
                ious.append(np.count_nonzero(mask & true_mask) / union)
    env.close()
    return {
        "position_mm": {
            "n": len(errors_mm),
            "median": float(np.median(errors_mm)),
            "p95": float(np.percentile(errors_mm, 95)),
        },
        "blocks_missed": missed,
        "segmentation_iou": {"n": len(ious), "mean": float(np.mean(ious)), "median": float(np.median(ious))},
        "scenes": scenes,
    }


def planned_grasps(scenes: int, randomization: bool) -> dict:
    options = (("randomization", True),) if randomization else ()
    first = 0
    for scene in range(scenes):
        spec = EpisodeSpec("planned", "Grasp", GRASP_SEED + scene, (("shapes", ("cube",)), *options))
        env = make_env(spec)
        result = play_episode(env, make_agent(spec, env), spec)["result"]
        env.close()
        first += result["grasps_attempted"] >= 1 and result["grasps_succeeded"] >= 1 and result["actions"] == 1
    return rate(first, scenes)


def grid(path: Path, scenes: int = 8) -> None:
    """The front camera on ``scenes`` randomised resets, 4 to a row."""
    import imageio.v3 as iio

    env = gym.make(
        "panda_grasp_env:PandaTowerBuild-v0", render_mode="rgb_array", render_size=(320, 240), randomization=True
    )
    frames = []
    for scene in range(scenes):
        env.reset(seed=SCENE_SEED + scene)
        frames.append(env.render())
    env.close()
    rows = [np.concatenate(frames[i : i + 4], axis=1) for i in range(0, scenes, 4)]
    path.parent.mkdir(parents=True, exist_ok=True)
    iio.imwrite(path, np.concatenate(rows, axis=0))


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--scenes", type=int, default=200)
    parser.add_argument("--grasp-scenes", type=int, default=200)
    parser.add_argument("--out", type=Path, default=Path("results/benchmarks/randomization.json"))
    parser.add_argument("--grid", type=Path, default=None, help="also write the image grid here (PNG)")
    parser.add_argument("--resume", action="store_true")
    args = parser.parse_args()
    results = Results(args.out, args.resume)
    for on in (False, True):
        label = "on " if on else "off"
        p = results.section(f"perception_{label.strip()}", lambda on=on: perception(args.scenes, on))
        print(
            f"randomisation {label}: block position median {p['position_mm']['median']:.2f} mm, "
            f"p95 {p['position_mm']['p95']:.2f} mm (n={p['position_mm']['n']}, missed {p['blocks_missed']}); "
            f"segmentation IoU mean {p['segmentation_iou']['mean']:.3f} ({p['scenes']} scenes)"
        )
    for on in (False, True):
        label = "on " if on else "off"
        g = results.section(f"grasps_{label.strip()}", lambda on=on: planned_grasps(args.grasp_scenes, on))
        low, high = g["ci95"]
        print(
            f"randomisation {label}: planned first-grasp success on isolated cubes {100 * g['rate']:.1f} % "
            f"({g['successes']}/{g['n']}, 95 % CI {100 * low:.1f}-{100 * high:.1f} %)"
        )
    print("(goal with it on: position median <= 2 mm, IoU >= 0.93, grasp success >= 97 %)")
    if args.grid is not None:
        grid(args.grid)
        print(f"image grid: {args.grid}")
    print(f"saved {args.out}")


if __name__ == "__main__":
    main()
