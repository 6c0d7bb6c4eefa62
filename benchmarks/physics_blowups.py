"""How often the physics blows up under a shipped low-level policy: a free body launched, a finger thrown open.

    python benchmarks/physics_blowups.py [--checkpoints lift_sac_her,push_sac_her] [--episodes N]
                                         [--speed 2.0] [--out results/benchmarks/physics_blowups.json] [--resume]

Each checkpoint plays its own env on its held-out test seeds (``eval_seed + TEST_SEED_OFFSET``...).  After
every 25 Hz control step the script reads every free body's linear speed (m/s, world frame) and both finger
joints' positions (m); an episode counts as a blow-up when a free body moved faster than ``--speed`` (blocks
and objects are pushed and carried at well under 1 m/s) or a finger stood more than 2 cm outside its
0-0.04 m range.  Printed: blow-ups / episodes with a 95 % Wilson interval, the policy's success on the same
episodes, and each blow-up's seed, peak speed, peak finger position and the reset's object shapes.
"""

from __future__ import annotations

import argparse
import sys
from functools import partial
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))
import panda_grasp_env  # noqa: E402, F401  (first: it chooses MUJOCO_GL before mujoco is imported)

# isort: split

import mujoco
import numpy as np

from benchmarks._common import Results, rate, shipped_checkpoints
from panda_grasp_env.agents.learning.config import TEST_SEED_OFFSET
from panda_grasp_env.agents.policies.learned import Checkpoint, LearnedAgent
from panda_grasp_env.model.robot import FINGER_OPEN
from panda_grasp_env.sim.workcell import Workcell

#: How far outside its range a finger joint may stand before the episode counts as blown up, metres.
FINGER_SLACK = 0.02


class PeakTracker:
    """A workcell step observer: the largest free-body speed and finger position since ``clear``."""

    def __init__(self, cell: Workcell) -> None:
        model = cell.model
        free = np.flatnonzero(model.jnt_type == mujoco.mjtJoint.mjJNT_FREE)
        self.linear_dofs = [slice(adr, adr + 3) for adr in model.jnt_dofadr[free]]
        self.finger_qpos = cell.robot.finger_qpos_idx
        self.clear()

    def clear(self) -> None:
        self.speed, self.finger = 0.0, 0.0

    def __call__(self, cell: Workcell) -> None:
        qvel = cell.data.qvel
        self.speed = max([self.speed] + [float(np.linalg.norm(qvel[dofs])) for dofs in self.linear_dofs])
        self.finger = max(self.finger, float(np.max(np.abs(cell.data.qpos[self.finger_qpos]))))


def measure(name: str, episodes: int | None, speed_limit: float) -> dict:
    checkpoint = Checkpoint(name)
    env = checkpoint.make_env()
    agent = LearnedAgent(name, env)
    cell = env.unwrapped.cell
    tracker = PeakTracker(cell)
    cell.physics.add_observer(tracker)
    first = checkpoint.config.eval_seed + TEST_SEED_OFFSET
    n = episodes or checkpoint.config.final_eval_episodes
    blowups, successes = [], 0
    for seed in range(first, first + n):
        observation, info = env.reset(seed=seed)
        shapes = info.get("shapes")
        agent.reset(observation, info)
        tracker.clear()
        terminated = truncated = False
        while not (terminated or truncated):
            observation, _, terminated, truncated, info = env.step(agent.act(observation, info))
        successes += bool(info["is_success"])
        if tracker.speed > speed_limit or tracker.finger > FINGER_OPEN + FINGER_SLACK:
            blowups.append(
                {"seed": seed, "speed": round(tracker.speed, 2), "finger": round(tracker.finger, 3), "shapes": shapes}
            )
    env.close()
    return {
        "episodes": n,
        "blowups": rate(len(blowups), n),
        "success": rate(successes, n),
        "cases": blowups,
        "speed_limit": speed_limit,
    }


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--checkpoints", default=None, help="comma-separated names (default: every low-level one)")
    parser.add_argument("--episodes", type=int, default=None, help="default: each run's final_eval_episodes")
    parser.add_argument("--speed", type=float, default=2.0, help="free-body speed that counts as launched, m/s")
    parser.add_argument("--out", type=Path, default=Path("results/benchmarks/physics_blowups.json"))
    parser.add_argument("--resume", action="store_true", help="keep the sections already in --out")
    args = parser.parse_args()
    if not args.speed > 0:
        raise ValueError(f"--speed must be > 0 m/s, got {args.speed}")
    names = args.checkpoints.split(",") if args.checkpoints else shipped_checkpoints(heightmap=False)
    for name in names:
        Checkpoint(name)  # unknown names fail before anything runs
    results = Results(args.out, args.resume)
    episodes = args.episodes or "final_eval_episodes"
    for name in names:
        row = results.section(f"{name}/{episodes}/{args.speed}", partial(measure, name, args.episodes, args.speed))
        blown, success = row["blowups"], row["success"]
        print(
            f"{name}: blow-ups {blown['successes']}/{row['episodes']} = {blown['rate']:.1%} "
            f"({blown['ci95'][0]:.1%}-{blown['ci95'][1]:.1%}); success {success['rate']:.1%}"
        )
        for case in row["cases"]:
            print(f"    seed {case['seed']}: {case['speed']} m/s, finger {case['finger']} m, shapes {case['shapes']}")


if __name__ == "__main__":
    main()
