"""Pictures of structure episodes: the goal, and what the greedy and the lookahead planner left standing.

    python benchmarks/structure_episodes.py [--seed 100] [--out docs/images/structure_episodes.png]

One row per structure (``ROWS``): the goal laid out exactly where the episode's layout put it, then the last
state of ``planned`` (greedy, heightmap) and of ``planned_lookahead`` on the same seed, each captioned with
the outcome (success, or the task's failure reason) and the actions taken.  Prints the same.  The rates are
``evaluate.py``'s (docs/structures.md); this shows what the failures look like.
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))
import panda_grasp_env  # noqa: E402, F401  (first: it chooses MUJOCO_GL before mujoco is imported)

# isort: split

import gymnasium as gym
import mujoco
import numpy as np

from panda_grasp_env.agents.evaluation.benchmarks import STRUCTURE_OPTIONS
from panda_grasp_env.agents.policies.structures import lookahead_planner, structure_planner
from panda_grasp_env.model.scene import SceneConfig
from panda_grasp_env.model.structure_suite import SUITE
from panda_grasp_env.model.structures import structure_scene
from panda_grasp_env.sim.rendering import CameraRenderer
from panda_grasp_env.sim.structure_layout import stand_pieces
from panda_grasp_env.sim.workcell import Workcell
from panda_grasp_env.tooling.runs import atomic_path
from panda_grasp_env.tooling.video import write_lines

#: The structures shown, one per row: where order, the fingers' room and a scaffold decide.
ROWS = ("seesaw", "counterweight_tower", "ring_8", "cantilever", "lookout")
TILE = (320, 240)
PLANNERS = {"planned": lambda env, seed: structure_planner(env, seed, False), "planned_lookahead": lookahead_planner}


def view(cell: Workcell, origin: np.ndarray, heading: float) -> np.ndarray:
    """The scene around ``origin`` (table point, metres), seen across the structure's x axis."""
    camera = mujoco.MjvCamera()
    camera.lookat[:] = [*origin, 0.1]
    camera.distance, camera.azimuth, camera.elevation = 0.8, np.degrees(heading) + 70.0, -25.0
    renderer = CameraRenderer(cell.model, *TILE, profile="pretty")
    frame = renderer.render(cell.data, camera).copy()
    renderer.close()
    return frame


def episode(name: str, agent: str, seed: int) -> tuple[np.ndarray, np.ndarray, float]:
    """Play ``agent`` on structure ``name`` from ``seed``; its last frame, and the layout's origin and heading."""
    env = gym.make("panda_grasp_env:PandaStructure-v0", structure=name, **STRUCTURE_OPTIONS)
    planner = PLANNERS[agent](env, seed)
    observation, info = env.reset(seed=seed)
    targets = info["n_targets"]
    planner.reset(observation, info)
    actions, done = 0, False
    while not done:  # the env's step limit ends it
        observation, _, terminated, truncated, info = env.step(planner.act(observation, info))
        actions, done = actions + 1, terminated or truncated
    layout = env.unwrapped.task.layout
    outcome = "success" if info["is_success"] else info.get("failure_reason") or "step limit"
    frame = view(env.unwrapped.cell, layout.origin, layout.heading)
    write_lines(frame, [f"{agent}: {outcome}", f"{actions} actions, {info['in_place']}/{targets} in place"])
    print(f"{name:20s} seed {seed} {agent:18s} {outcome:14s} {actions:3d} actions")
    env.close()
    return frame, layout.origin, layout.heading


def goal(name: str, origin: np.ndarray, heading: float) -> np.ndarray:
    structure = SUITE[name]
    cell = Workcell(structure_scene(SceneConfig(), structure))
    cell.clear()
    stand_pieces(cell, structure, list(structure.pieces), cell.object_ids[: len(structure.pieces)], origin, heading)
    frame = view(cell, origin, heading)
    write_lines(frame, [f"{name}: the goal"])
    return frame


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--seed", type=int, default=100)
    parser.add_argument("--out", type=Path, default=Path("docs/images/structure_episodes.png"))
    args = parser.parse_args()
    import imageio.v3 as iio

    rows = []
    for name in ROWS:
        frames = [episode(name, agent, args.seed) for agent in PLANNERS]
        _, origin, heading = frames[0]
        rows.append(np.concatenate([goal(name, origin, heading), *(f for f, _, _ in frames)], axis=1))
    with atomic_path(args.out) as path:
        iio.imwrite(path, np.concatenate(rows, axis=0), extension=".png")
    print(f"wrote {args.out}")


if __name__ == "__main__":
    main()
