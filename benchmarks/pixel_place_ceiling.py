"""How well can anything build through the ``pixel`` actions the structure learner uses?  An oracle that knows
every piece's pose picks, for each target from the lowest up, a loose piece of its kind, grasps it at the cell
nearest its centre, and places it at the cell nearest the target, with the rotations nearest the grip that
turns the piece onto the target's heading with the fingers across the direction to the nearest piece built
beside it.  ``--stride 4`` first rounds both cells to the network's
quarter-resolution grid (every 4th cell, 16 mm), as its scores are upsampled from; ``--stride 2`` to the refined
network's (every 2nd cell, 8 mm).

    python benchmarks/pixel_place_ceiling.py [--episodes 20] [--seed-start 5000000] [--rotations 32] [--stride 1]

Prints trial success with its 95 % Wilson interval, per tier, and the place failures.  Seeds 5000000 on are the
generated structures of tiers 1-4 with up to 6 pieces (configs/structure_builder_dqn.yaml's env): no training,
validation or test seed of that config.
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

from panda_grasp_env.agents.evaluation.metrics import wilson
from panda_grasp_env.model.structures import grip_headings, symmetry, wrapped
from panda_grasp_env.perception.heightmap import HeightmapGrid
from panda_grasp_env.tasks.structure_build import GOAL_FIELDS, read_rows

BOUNDS = ((0.24, 0.76), (-0.36, 0.36), (0.0, 0.45))


def action(shape: tuple[int, ...], grid: HeightmapGrid, primitive: int, xy: np.ndarray, yaw: float, stride: int) -> int:
    """The pixel action of ``primitive`` at the cell nearest world point ``xy`` (on every ``stride``-th cell) and
    the rotation nearest heading ``yaw`` (radians).  (The network's quarter-resolution grid lies in each
    rotation's frame; every 4th cell of the world grid has the same spacing.)"""
    _, rotations, rows, cols = shape
    row, col = np.round(grid.cell_position(np.asarray(xy)) / stride) * stride
    row, col = int(np.clip(row, 0, rows - 1)), int(np.clip(col, 0, cols - 1))
    rotation = int(round(wrapped(yaw, 2 * np.pi) / (2 * np.pi / rotations))) % rotations
    return int(np.ravel_multi_index((primitive, rotation, row, col), shape))


def clearest_heading(kind: str, targets: np.ndarray, yaws: np.ndarray, index: int, built: list[int]) -> float:
    """The closing-axis heading (radians) that grips target ``index``'s piece as it stands there and points the
    fingers away from the built targets beside it at its level: the one most across the direction to the
    nearest of them (fingers opened along a row would strike the row's last piece)."""
    headings = grip_headings(kind, float(yaws[index]))
    beside = [j for j in built if abs(targets[j, 2] - targets[index, 2]) < 0.01]
    if not beside:
        return headings[0]
    nearest = min(beside, key=lambda j: np.linalg.norm(targets[j, :2] - targets[index, :2]))
    direction = np.arctan2(*(targets[nearest, 1::-1] - targets[index, 1::-1]))
    return max(headings, key=lambda h: abs(np.sin(h - direction)))


def play(env: gym.Env, seed: int, stride: int) -> tuple[bool, int, Counter]:
    observation, info = env.reset(seed=seed)
    tier = int(info["tier"])
    layout = info["action_layout"]
    shape, grid = tuple(layout["shape"]), HeightmapGrid.of_layout(layout)
    primitives = layout["primitives"]
    kinds, targets, target_yaws = read_rows(observation["desired_goal"].reshape(-1, GOAL_FIELDS)[: info["n_targets"]])
    used: set[int] = set()
    built: list[int] = []
    failures: Counter = Counter()
    for index in np.argsort(targets[:, 2], kind="stable"):
        rows = observation["achieved_goal"].reshape(-1, GOAL_FIELDS)
        piece_kinds, centres, yaws = read_rows(rows[rows[:, 6] > 0.5])
        free = [s for s, k in enumerate(piece_kinds) if k == kinds[index] and s not in used]
        slot = free[0]
        used.add(slot)
        place = clearest_heading(kinds[index], targets, target_yaws, index, built)
        built.append(index)
        grip = place - wrapped(target_yaws[index] - yaws[slot], 2 * np.pi / symmetry(kinds[index]))
        for primitive, xy, yaw in (("grasp", centres[slot, :2], grip), ("place", targets[index, :2], place)):
            observation, _, terminated, truncated, info = env.step(
                action(shape, grid, primitives.index(primitive), xy, yaw, stride)
            )
            if not info["primitive_success"]:
                failures[f"{primitive}: {info['primitive_reason']}"] += 1
            if terminated or truncated:
                return bool(info["is_success"]), tier, failures
    return bool(info["is_success"]), tier, failures


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--episodes", type=int, default=20)
    parser.add_argument("--seed-start", type=int, default=5_000_000)
    parser.add_argument("--rotations", type=int, default=32)
    parser.add_argument(
        "--stride", type=int, default=1, help="cells between the aims allowed: 1, 2 (the refined network) or 4"
    )
    args = parser.parse_args()
    env = gym.make(
        "PandaStructure-v0",
        obs_mode="heightmap",
        action_mode="pixel",
        heightmap_bounds=BOUNDS,
        heightmap_resolution=0.004,
        rotations=args.rotations,
        structure="random",
        tiers=[1, 2, 3, 4],
        max_pieces=6,
        max_episode_steps=30,
    )
    by_tier: dict[int, list[bool]] = {}
    failures: Counter = Counter()
    for seed in range(args.seed_start, args.seed_start + args.episodes):
        success, tier, failed = play(env, seed, args.stride)
        by_tier.setdefault(tier, []).append(success)
        failures.update(failed)
    won = [s for results in by_tier.values() for s in results]
    low, high = wilson(sum(won), len(won))
    print(
        f"rotations {args.rotations}, aims every {args.stride} cell(s) ({4 * args.stride} mm), seeds "
        f"{args.seed_start}-{args.seed_start + args.episodes - 1}"
    )
    print(f"trial success {sum(won)}/{len(won)} ({100 * low:.0f}-{100 * high:.0f} %)")
    for tier in sorted(by_tier):
        print(f"  tier {tier}: {sum(by_tier[tier])}/{len(by_tier[tier])}")
    print(f"failed primitives: {dict(failures)}")


if __name__ == "__main__":
    main()
