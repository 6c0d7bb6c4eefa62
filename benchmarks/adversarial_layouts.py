"""Grasp-only against push-aware grasping on the hand-designed packed layouts, per layout, in one run.

    python benchmarks/adversarial_layouts.py [--runs 5] [--first-seed 700000] [--agents grasp_only,push_aware]
                                             [--layouts 0,1,...] [--heaps N] [--heap-first-seed 1100000]
                                             [--out results/benchmarks/adversarial_layouts.json] [--resume]

``PandaGraspAdversarial-v0`` with ``layout=i``; run ``k`` of a layout is seed ``--first-seed + 100 * i + k``
(the seed draws the layout's pose jitter).  Agents:

* ``grasp_only``: true object poses (``panda_grasp_env.agents.policies.grasping.PackedGraspOracle``), the best grasp
  whose fingers clear every other object, never a push;
* ``push_aware``: the same, and a planned push when no such grasp is left;
* any shipped heightmap checkpoint by name (e.g. ``grasp_clutter_dqn``, grasps only; ``push_grasp_dqn``),
  on the env options it was trained with (``evaluate.py``'s env for it on that task).

``--heaps N`` adds N random heaps of ``PandaGraspClutter-v0`` (VPG's protocol; seeds ``--heap-first-seed``
... , held out from every shipped heightmap policy's training and validation): pushing where it is not
needed must not cost a policy its clearing there.  ``--layouts none`` runs the heaps alone.

Printed per layout and agent: the objects grasped (of those in play), the runs that grasped every object
(trial success: the table cleared by grasps, not by pushing things out of reach) with its 95 % interval
over the runs, grasp success, action efficiency (the objects of the cleared runs per action, VPG's),
the share of pushes among the actions and of pushes followed by a successful grasp, and the objects other
than the target that each action disturbed, and the episodes a physics error ended (an object thrown by the
contact solver; see docs/environments.md, "Bad input").
Goals (issue 32): grasp-only well below 100 %; push-aware completion >= 90 %, grasp success >= 85 %; on
random heaps the push-grasp policy keeps completion >= 95 % at efficiency >= 80 %.
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))
import panda_grasp_env  # noqa: E402, F401  (first: it chooses MUJOCO_GL before mujoco is imported)

# isort: split

import gymnasium as gym  # noqa: E402

from benchmarks._common import Results, wilson  # noqa: E402
from panda_grasp_env.agents.evaluation.protocol import learned_env  # noqa: E402
from panda_grasp_env.agents.policies.grasping import PackedGraspOracle  # noqa: E402
from panda_grasp_env.agents.policies.learned import Checkpoint, LearnedAgent, available_checkpoints  # noqa: E402
from panda_grasp_env.tasks.packed_layouts import ADVERSARIAL_LAYOUTS  # noqa: E402

AGENTS = {"grasp_only": False, "push_aware": True}


def episode(agent_name: str, layout: int | None, seed: int) -> dict[str, float]:
    """One episode's counts, on packed layout ``layout`` or (None) a random heap."""
    env_id, scene = ("PandaGraspClutter-v0", {}) if layout is None else ("PandaGraspAdversarial-v0", {"layout": layout})
    if agent_name in AGENTS:
        env = gym.make(f"panda_grasp_env:{env_id}", **scene, primitive_z=True)
        agent = PackedGraspOracle(env, seed=seed, pushes=AGENTS[agent_name])
    else:
        env = learned_env(Checkpoint(agent_name), "GraspClutter" if layout is None else "GraspAdversarial", **scene)
        agent = LearnedAgent(agent_name, env)
    observation, info = env.reset(seed=seed)
    agent.reset(observation, info)
    in_play = info["objects_remaining"]
    counts = {"actions": 0, "grasps": 0, "grasped": 0, "pushes": 0, "pushes_then_grasp": 0, "disturbed": 0}
    after_push, done = False, False
    while not done:
        observation, _, terminated, truncated, info = env.step(agent.act(observation, info))
        done = terminated or truncated
        counts["actions"] += 1
        counts["disturbed"] += info.get("disturbed", 0)
        if info.get("primitive") == "push":
            counts["pushes"] += 1
            after_push = True
            continue
        counts["grasps"] += 1
        if info.get("primitive_success"):
            counts["grasped"] += 1
            counts["pushes_then_grasp"] += int(after_push)
        after_push = False
    env.close()
    return {
        **counts,
        "in_play": in_play,
        "cleared": int(info["is_success"]),
        "physics_errors": int(info["physics_error"]),
    }


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--runs", type=int, default=5, help="jitter seeds per layout")
    parser.add_argument("--first-seed", type=int, default=700_000)
    parser.add_argument("--agents", default=",".join(AGENTS))
    parser.add_argument("--layouts", default=None, help="comma-separated indices, or none (default: all)")
    parser.add_argument("--heaps", type=int, default=0, help="random heaps (PandaGraspClutter-v0) besides")
    parser.add_argument("--heap-first-seed", type=int, default=1_100_000)
    parser.add_argument("--out", type=Path, default=Path("results/benchmarks/adversarial_layouts.json"))
    parser.add_argument("--resume", action="store_true", help="keep episodes already saved in --out")
    args = parser.parse_args()
    names = list(ADVERSARIAL_LAYOUTS)
    if args.layouts is None:
        layouts = list(range(len(names)))
    else:
        layouts = [] if args.layouts == "none" else [int(i) for i in args.layouts.split(",")]
    agents = args.agents.split(",")
    unknown = sorted(set(agents) - set(AGENTS) - set(available_checkpoints()))
    if unknown or args.runs < 1 or args.heaps < 0 or any(not 0 <= i < len(names) for i in layouts):
        raise ValueError(
            f"--agents from {list(AGENTS)} or shipped checkpoints, --runs >= 1, --heaps >= 0, "
            f"--layouts in [0, {len(names) - 1}] or none"
        )
    results = Results(args.out, args.resume)
    print(
        f"{'layout':26s} {'agent':18s} {'grasped':>10s} {'cleared (95 % CI)':>22s} {'grasp ok':>8s} "
        f"{'effic.':>6s} {'pushes':>6s} {'push->grasp':>11s} {'disturbed/act':>13s} {'physics errors':>14s}"
    )
    totals = {agent: [] for agent in agents}
    for index in layouts:
        for agent in agents:
            rows = [
                results.section(
                    f"{agent}/{index}/{seed}", lambda seed=seed, agent=agent, index=index: episode(agent, index, seed)
                )
                for seed in range(args.first_seed + 100 * index, args.first_seed + 100 * index + args.runs)
            ]
            totals[agent] += rows
            report(names[index], agent, rows)
    if layouts:
        for agent in agents:
            report("all layouts", agent, totals[agent])
    seeds = range(args.heap_first_seed, args.heap_first_seed + args.heaps)
    if seeds:
        for agent in agents:
            rows = [
                results.section(f"{agent}/heap/{seed}", lambda seed=seed, agent=agent: episode(agent, None, seed))
                for seed in seeds
            ]
            report(f"random heaps ({len(rows)})", agent, rows)


def report(label: str, agent: str, rows: list[dict[str, float]]) -> None:
    total = {key: sum(row.get(key, 0) for row in rows) for key in set().union(*rows)}  # older files: no new keys
    low, high = wilson(total["cleared"], len(rows))
    print(
        f"{label:26s} {agent:18s} {total['grasped'] / max(total['in_play'], 1):10.1%} "
        f"{total['cleared']:3d}/{len(rows):<3d} ({low:5.1%}-{high:6.1%}) "
        f"{total['grasped'] / max(total['grasps'], 1):8.1%} "
        f"{sum(row['in_play'] for row in rows if row['cleared']) / max(total['actions'], 1):6.1%} "
        f"{total['pushes'] / max(total['actions'], 1):6.1%} "
        f"{total['pushes_then_grasp'] / max(total['pushes'], 1):11.1%} {total['disturbed'] / max(total['actions'], 1):13.2f} "
        f"{total['physics_errors']:14d}"
    )


if __name__ == "__main__":
    main()
