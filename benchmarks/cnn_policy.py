"""Off-the-shelf SB3 ``CnnPolicy`` on this project's heightmaps: sb3-contrib's MaskablePPO on ``pixel_factored``.

    python benchmarks/cnn_policy.py [--env PandaGraspClutter-v0] [--steps 256] [--resolution 0.004] [--rotations 4]

The env's ``heightmap`` observation is (rows, cols, 4) float32, channels last (colour 0-1, height in metres),
which SB3's ``CnnPolicy`` cannot take; ``panda_grasp_env.agents.learning.heightmap_policy.EncodedHeightmap`` gives it as
(4, rows, cols) uint8, channels first (height in millimetres up to 255), which it takes as it is.  This runs
MaskablePPO (``CnnPolicy``: SB3's NatureCNN, the env's ``action_masks``) for ``--steps`` env steps on one torch
thread and prints the policy's parameter count, the process's peak resident memory and the wall time.
"""

from __future__ import annotations

import argparse
import resource
import sys
import time

import panda_grasp_env  # noqa: E402, F401  (first: it chooses MUJOCO_GL before mujoco is imported)

# isort: split


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--env", default="PandaGraspClutter-v0")
    parser.add_argument("--steps", type=int, default=256)
    parser.add_argument("--resolution", type=float, default=0.004, help="heightmap cell size, metres")
    parser.add_argument("--rotations", type=int, default=4)
    args = parser.parse_args()

    import gymnasium as gym
    import torch
    from sb3_contrib import MaskablePPO

    from panda_grasp_env.agents.learning.heightmap_observations import EncodedHeightmap

    torch.set_num_threads(1)
    start = time.perf_counter()
    env = EncodedHeightmap(
        gym.make(
            f"panda_grasp_env:{args.env}",
            action_mode="pixel_factored",
            obs_mode="heightmap",
            heightmap_resolution=args.resolution,
            rotations=args.rotations,
        )
    )
    model = MaskablePPO("CnnPolicy", env, n_steps=64, batch_size=32, n_epochs=1, seed=0, device="cpu")
    parameters = sum(p.numel() for p in model.policy.parameters())
    model.learn(args.steps)
    wall = time.perf_counter() - start
    peak = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024  # KiB on Linux
    print(f"{args.env}: observation {env.observation_space}, actions {env.action_space}")
    print(
        f"MaskablePPO CnnPolicy: {parameters:,} parameters; {model.num_timesteps} env steps in {wall:.0f} s "
        f"({model.num_timesteps / wall:.2f} steps/s, one torch thread); peak resident memory {peak:.0f} MiB"
    )
    env.close()


if __name__ == "__main__":
    sys.exit(main())
