"""Perception against the simulator's ground truth, over seeded scenes.

    python benchmarks/perception_quality.py [--scenes 500] [--out results/benchmarks/perception.json] [--resume]

* block pose error (position: 3-D distance of centres, mm; yaw modulo 90 degrees)
  from the overhead and front cameras at 640x480, half the scenes scattered and
  half a standing tower, with the Kinect-like noise model on and off
  (goal with noise: median <= 2 mm, 95th percentile <= 5 mm, median yaw <= 2 deg):
  by colour (``estimate_block_poses``) and by shape from depth alone
  (``estimate_block_poses_from_depth``, whose anonymous blocks are paired with the
  true ones by least total distance; one farther than half a block from its pair is
  missed, and estimates left over are extra);
* tower detection: the detected stack equals the true bottom-up order;
* colour segmentation IoU per colour against the simulator's segmentation
  render, over the pixels either marks (goal: mean >= 0.95);
* heightmap time for the default 224 x 224 grid from one 640x480 RGB-D image (goal <= 10 ms);
* grasp detection: the top-ranked candidate from the overhead 640x480 depth,
  executed by the grasp primitive through ``PandaGrasp-v0`` (``primitive_z=True``),
  on one isolated object per scene, per shape (goal: cubes >= 95 %, other
  shapes >= 90 %), and the time per detection (goal <= 50 ms on one core).

Numerical libraries run single-threaded here (one core, as the goal says).
"""

from __future__ import annotations

import argparse
import os
import statistics
import sys
import time
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))
import panda_grasp_env  # noqa: E402, F401  (first: it chooses MUJOCO_GL before mujoco is imported)

# isort: split
for _threads in ("OMP_NUM_THREADS", "OPENBLAS_NUM_THREADS", "MKL_NUM_THREADS"):
    os.environ.setdefault(_threads, "1")

import gymnasium as gym
import numpy as np
from scipy.optimize import linear_sum_assignment

from benchmarks._common import Results, rate
from panda_grasp_env.perception.camera import CameraModel
from panda_grasp_env.perception.grasps import detect_grasps_rgbd
from panda_grasp_env.perception.heightmap import HeightmapGrid, heightmap_from_rgbd
from panda_grasp_env.perception.noise import DepthNoise, RGBNoise
from panda_grasp_env.perception.pose import (
    BlockPose,
    View,
    detect_towers,
    estimate_block_poses,
    estimate_block_poses_from_depth,
    wrap_quarter,
)
from panda_grasp_env.perception.segmentation import colour_masks
from panda_grasp_env.sim.rendering import CameraRenderer
from panda_grasp_env.sim.workcell import Workcell

CAMERAS = ("overhead", "front")
SIZE = (640, 480)


def capture(cell: Workcell, renderer: CameraRenderer, noise_rng: np.random.Generator | None) -> list[View]:
    views = []
    for camera in CAMERAS:
        rgb, depth = renderer.render_rgbd(cell.data, camera)
        if noise_rng is not None:
            rgb, depth = RGBNoise().apply(rgb, noise_rng), DepthNoise().apply(depth, noise_rng)
        views.append(View(rgb, depth, CameraModel.from_mujoco(cell.model, cell.data, camera, *SIZE)))
    return views


def paired_with_truth(seen: list[BlockPose], cell: Workcell) -> dict[str, BlockPose]:
    """Anonymous estimates named after the true blocks they pair with (least total distance); a pair farther
    apart than half a block is no pair."""
    positions = cell.block_positions()
    distances = np.linalg.norm(np.array([p.position for p in seen]).reshape(-1, 1, 3) - positions[None], axis=2)
    rows, columns = linear_sum_assignment(distances)
    return {cell.block_names[c]: seen[r] for r, c in zip(rows, columns) if distances[r, c] < cell.config.block_size / 2}


def pose_errors(scenes: int, noise: bool, by_depth: bool = False) -> dict:
    """Pose errors over ``scenes`` seeded scenes: by colour, or (``by_depth``) by shape from depth alone."""
    cell = Workcell()
    colours = dict(zip(cell.block_names, cell.config.colours.values()))
    position_mm: dict[str, list[float]] = {"scattered": [], "tower": []}
    yaw_deg: dict[str, list[float]] = {"scattered": [], "tower": []}
    missed, extra, towers_right, seconds = 0, 0, 0, []
    with CameraRenderer(cell.model, *SIZE) as renderer:
        for scene in range(scenes):
            layout = "scattered" if scene % 2 == 0 else "tower"
            cell.reset(np.random.default_rng(scene), layout)
            views = capture(cell, renderer, np.random.default_rng(10_000 + scene) if noise else None)
            start = time.perf_counter()
            if by_depth:
                seen = estimate_block_poses_from_depth(views, cell.config.block_size)
                seconds.append(time.perf_counter() - start)
                poses = paired_with_truth(seen, cell)
                extra += len(seen) - len(poses)
            else:
                poses = estimate_block_poses(views, colours, cell.config.block_size)
                seconds.append(time.perf_counter() - start)
            positions, yaws = cell.block_positions(), cell.block_yaws()
            for index, name in enumerate(cell.block_names):
                if name not in poses:
                    missed += 1
                    continue
                position_mm[layout].append(1000 * float(np.linalg.norm(poses[name].position - positions[index])))
                yaw_deg[layout].append(abs(np.degrees(wrap_quarter(poses[name].yaw - yaws[index]))))
            if layout == "tower":
                truth = [cell.block_names[i] for i in np.argsort(positions[:, 2])]
                towers_right += detect_towers({n: p.position for n, p in poses.items()}, cell.config.block_size) == [
                    truth
                ]

    def summary(values: list[float]) -> dict:
        return {"n": len(values), "median": float(np.median(values)), "p95": float(np.percentile(values, 95))}

    every_position = position_mm["scattered"] + position_mm["tower"]
    every_yaw = yaw_deg["scattered"] + yaw_deg["tower"]
    return {
        "position_mm": summary(every_position),
        "yaw_deg": summary(every_yaw),
        "by_layout": {k: {"position_mm": summary(position_mm[k]), "yaw_deg": summary(yaw_deg[k])} for k in position_mm},
        "blocks_missed": missed,
        "blocks_extra": extra,
        "blocks_total": scenes * len(cell.block_names),
        "towers_detected_right": towers_right,
        "tower_scenes": scenes // 2,
        "ms_per_estimate_median": 1000 * statistics.median(seconds),
    }


def segmentation_iou(scenes: int, light_scale: float = 1.0) -> dict:
    cell = Workcell()
    cell.model.light_diffuse[:] *= light_scale  # dimmer or brighter scene: thresholds must still hold
    colours = dict(zip(cell.block_names, cell.config.colours.values()))
    geom_of = {name: cell.model.body_geomadr[cell.model.body(name).id] for name in cell.block_names}
    ious: dict[str, list[float]] = {name: [] for name in cell.block_names}
    with CameraRenderer(cell.model, *SIZE) as renderer:
        for scene in range(scenes):
            cell.reset(np.random.default_rng(scene), "scattered" if scene % 2 == 0 else "tower")
            for camera in CAMERAS:
                rgb, _ = renderer.render_rgbd(cell.data, camera)
                rgb = RGBNoise().apply(rgb, np.random.default_rng(20_000 + scene))
                truth = renderer.render(cell.data, camera, "segmentation")
                for name, mask in colour_masks(rgb, colours).items():
                    true_mask = truth == geom_of[name]
                    union = np.count_nonzero(mask | true_mask)
                    if union:
                        ious[name].append(np.count_nonzero(mask & true_mask) / union)
    per_colour = {name: float(np.mean(values)) for name, values in ious.items()}
    return {"per_colour": per_colour, "mean": float(np.mean(list(per_colour.values()))), "views": 2 * scenes}


def heightmap_time(repeats: int = 50) -> dict:
    cell = Workcell()
    cell.reset(np.random.default_rng(0), "tower")
    grid = HeightmapGrid()
    with CameraRenderer(cell.model, *SIZE) as renderer:
        rgb, depth = renderer.render_rgbd(cell.data, "overhead")
    camera = CameraModel.from_mujoco(cell.model, cell.data, "overhead", *SIZE)
    times = []
    for _ in range(repeats):
        start = time.perf_counter()
        heights, _ = heightmap_from_rgbd(grid, camera, rgb, depth)
        times.append(time.perf_counter() - start)
    top_error = abs(float(heights.max()) - (cell.block_positions()[:, 2].max() + cell.config.block_size / 2))
    return {"ms_median": 1000 * statistics.median(times), "shape": list(grid.shape), "top_error_mm": 1000 * top_error}


def grasp_detection(shape: str, scenes: int) -> dict:
    env = gym.make("panda_grasp_env:PandaGrasp-v0", shapes=(shape,), primitive_z=True)
    unwrapped = env.unwrapped
    successes, reasons, seconds = 0, {}, []
    for scene in range(scenes):
        env.reset(seed=scene)
        _, depth = unwrapped.sensors.rgbd("overhead", *SIZE)
        camera = unwrapped.camera_model("overhead", *SIZE)
        start = time.perf_counter()
        candidates = detect_grasps_rgbd(depth, camera, np.random.default_rng(scene))
        seconds.append(time.perf_counter() - start)
        if not candidates:
            reasons["no_candidate"] = reasons.get("no_candidate", 0) + 1
            continue
        best = candidates[0]
        action = unwrapped.actions.encode("grasp", best.position[0], best.position[1], best.yaw, best.position[2])
        info = env.step(action)[4]
        successes += int(info["primitive_success"])
        reasons[info["primitive_reason"]] = reasons.get(info["primitive_reason"], 0) + 1
    env.close()
    return rate(successes, scenes) | {"reasons": reasons, "ms_per_detection_median": 1000 * statistics.median(seconds)}


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--scenes", type=int, default=500)
    parser.add_argument("--iou-scenes", type=int, default=100)
    parser.add_argument("--grasp-scenes", type=int, default=200, help="scenes per shape")
    parser.add_argument("--out", type=Path, default=Path("results/benchmarks/perception.json"))
    parser.add_argument("--resume", action="store_true")
    args = parser.parse_args()
    results = Results(args.out, args.resume)
    for by_depth, noise in ((False, True), (False, False), (True, True), (True, False)):
        section = f"pose_{'depth_' if by_depth else ''}noise_{noise}"
        r = results.section(section, lambda noise=noise, d=by_depth: pose_errors(args.scenes, noise, d))
        p, y = r["position_mm"], r["yaw_deg"]
        extra = f", extra {r['blocks_extra']}" if by_depth else ""
        print(
            f"block pose by {'depth' if by_depth else 'colour'}, noise {'on ' if noise else 'off'}: position median "
            f"{p['median']:.2f} mm, p95 {p['p95']:.2f} mm; yaw median {y['median']:.2f} deg, p95 {y['p95']:.2f} deg"
            f"  (n={p['n']}, missed {r['blocks_missed']}/{r['blocks_total']}{extra}; "
            f"{r['ms_per_estimate_median']:.0f} ms per scene)"
        )
        for layout, figures in r["by_layout"].items():
            print(
                f"    {layout:9s} position median {figures['position_mm']['median']:.2f} mm, "
                f"p95 {figures['position_mm']['p95']:.2f} mm; yaw median {figures['yaw_deg']['median']:.2f} deg"
            )
        print(f"    towers detected in the right order: {r['towers_detected_right']}/{r['tower_scenes']}")
    print("    (goal with noise: median <= 2 mm, p95 <= 5 mm, yaw median <= 2 deg)")
    iou = results.section("segmentation", lambda: segmentation_iou(args.iou_scenes))
    colours = ", ".join(f"{k.removeprefix('block_')} {v:.3f}" for k, v in iou["per_colour"].items())
    print(f"colour segmentation IoU: mean {iou['mean']:.3f} ({colours}; {iou['views']} views)  (goal >= 0.95)")
    for scale in (0.5, 1.5):
        lit = results.section(f"segmentation_light_{scale}", lambda s=scale: segmentation_iou(args.iou_scenes // 2, s))
        print(f"    with the lights at {scale:.1f}x: mean IoU {lit['mean']:.3f} ({lit['views']} views)")
    hm = results.section("heightmap", heightmap_time)
    print(
        f"heightmap {hm['shape']}: {hm['ms_median']:.1f} ms, tallest cell off by {hm['top_error_mm']:.2f} mm  (goal <= 10 ms)"
    )
    for shape in ("cube", "box", "cylinder", "sphere", "capsule"):
        g = results.section(f"grasp_{shape}", lambda shape=shape: grasp_detection(shape, args.grasp_scenes))
        low, high = g["ci95"]
        print(
            f"grasp detection, {shape:8s}: {100 * g['rate']:5.1f} % ({g['successes']}/{g['n']}, 95 % CI "
            f"{100 * low:.1f}-{100 * high:.1f} %) {g['reasons']}; {g['ms_per_detection_median']:.0f} ms per detection"
        )
    print("    (goal: cubes >= 95 %, other shapes >= 90 %; <= 50 ms per detection)")
    print(f"saved {args.out}")


if __name__ == "__main__":
    main()
