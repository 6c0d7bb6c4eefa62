"""The planned (scripted) agents through env.step, over seeded episodes.

    python benchmarks/agents.py [--isolated 200] [--shapes 100] [--clutter 30] [--towers 100]
                                [--out results/benchmarks/agents.json] [--resume]

* ``PlannedGraspAgent`` (perception, Kinect-like noise) on ``PandaGrasp-v0``: isolated cubes
  (first-attempt success, success within 3 attempts) and the other shapes; on
  ``PandaGraspClutter-v0`` VPG's metrics: completion (the workspace cleared without
  10 consecutive failures), grasp success (successful / attempted grasps) and
  action efficiency (objects in play / actions);
* ``TowerBuilderAgent`` (perception) and its oracle on ``PandaTowerBuild-v0``:
  trial success and action efficiency (6 ideal actions / actions used);
* ``TowerBreakerAgent`` (perception) on ``PandaTowerBreak-v0``;
* compute time per grasp attempt (perception + selection), one thread.
"""

from __future__ import annotations

import argparse
import os
import statistics
import sys
import time
from collections import Counter
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))
import panda_grasp_env  # noqa: E402, F401  (first: it chooses MUJOCO_GL before mujoco is imported)

# isort: split
for _threads in ("OMP_NUM_THREADS", "OPENBLAS_NUM_THREADS", "MKL_NUM_THREADS"):
    os.environ.setdefault(_threads, "1")

import gymnasium as gym

from benchmarks._common import Results, clustered_rate, describe_rate, rate
from panda_grasp_env.agents.policies.grasping import PlannedGraspAgent
from panda_grasp_env.agents.policies.towers import OracleBlocks, TowerBreakerAgent, TowerBuilderAgent

RGBD = {"obs_mode": "rgbd", "image_size": (640, 480)}


def run_episode(env: gym.Env, agent, seed: int) -> tuple[dict, list[dict]]:
    observation, info = env.reset(seed=seed)
    agent.reset(observation, info)
    return run_episode_from(env, agent, observation, info)


def isolated_grasps(shape: str, episodes: int, action_mode: str = "primitive") -> dict:
    env = gym.make("panda_grasp_env:PandaGrasp-v0", shapes=(shape,), primitive_z=True, action_mode=action_mode, **RGBD)
    agent = PlannedGraspAgent()
    first = within_three = 0
    failures, seconds, step_seconds = Counter(), [], []
    for seed in range(episodes):
        start = time.perf_counter()
        _, steps = run_episode(env, agent, seed)
        step_seconds.append((time.perf_counter() - start) / len(steps))
        outcomes = [s["primitive_success"] for s in steps if s.get("primitive") == "grasp"]
        first += bool(outcomes) and outcomes[0]
        within_three += any(outcomes[:3])
        failures.update(agent.failures)
        seconds += agent.compute_seconds
    env.close()
    return {
        "first_attempt": rate(first, episodes),
        "within_3": rate(within_three, episodes),
        "failures": dict(failures),
        "ms_per_attempt_median": 1000 * statistics.median(seconds),
        "ms_per_env_step_median": 1000 * statistics.median(step_seconds),
    }


def clutter(episodes: int) -> dict:
    env = gym.make("panda_grasp_env:PandaGraspClutter-v0", primitive_z=True, **RGBD)
    agent = PlannedGraspAgent()
    completed = actions = in_play = all_grasped = 0
    attempted, succeeded = [], []  # per episode
    failures, seconds = Counter(), []
    for seed in range(episodes):
        observation, info = env.reset(seed=seed)
        in_play += info["objects_remaining"]
        agent.reset(observation, info)
        final, steps = run_episode_from(env, agent, observation, info)
        completed += final["objects_remaining"] == 0
        all_grasped += final["is_success"]
        attempted.append(final["grasps_attempted"])
        succeeded.append(final["grasps_succeeded"])
        actions += len(steps)
        failures.update(agent.failures)
        seconds += agent.compute_seconds
    env.close()
    return {
        "completion": rate(completed, episodes),
        "every_object_grasped": rate(all_grasped, episodes),
        "grasp_success": clustered_rate(succeeded, attempted),
        "action_efficiency": in_play / actions,
        "actions": actions,
        "failures": dict(failures),
        "ms_per_attempt_median": 1000 * statistics.median(seconds),
    }


def run_episode_from(env: gym.Env, agent, observation, info) -> tuple[dict, list[dict]]:
    steps = []
    while True:
        observation, _, terminated, truncated, info = env.step(agent.act(observation, info))
        steps.append(info)
        if terminated or truncated:
            return info, steps


def towers(episodes: int, oracle: bool) -> dict:
    env = gym.make("panda_grasp_env:PandaTowerBuild-v0", cameras=("overhead", "front"), **RGBD)
    agent = TowerBuilderAgent(OracleBlocks(env) if oracle else None)
    successes, actions, failures = 0, 0, Counter()
    for seed in range(episodes):
        final, steps = run_episode(env, agent, seed)
        successes += final["is_success"]
        actions += len(steps)
        failures.update(agent.failures)
    env.close()
    return {
        "success": rate(successes, episodes),
        "action_efficiency": 6 * episodes / actions,
        "failures": dict(failures),
    }


def breaking(episodes: int) -> dict:
    env = gym.make("panda_grasp_env:PandaTowerBreak-v0", cameras=("overhead", "front"), **RGBD)
    agent = TowerBreakerAgent()
    successes, actions = 0, 0
    for seed in range(episodes):
        final, steps = run_episode(env, agent, seed)
        successes += final["is_success"]
        actions += len(steps)
    env.close()
    return {"success": rate(successes, episodes), "actions_per_trial": actions / episodes}


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--isolated", type=int, default=200, help="isolated-cube episodes")
    parser.add_argument("--shapes", type=int, default=100, help="episodes per other shape")
    parser.add_argument("--clutter", type=int, default=30)
    parser.add_argument("--pose", type=int, default=100, help="isolated-cube episodes through the motion stack")
    parser.add_argument("--towers", type=int, default=100)
    parser.add_argument("--out", type=Path, default=Path("results/benchmarks/agents.json"))
    parser.add_argument("--resume", action="store_true")
    args = parser.parse_args()
    counts = {name: getattr(args, name) for name in ("isolated", "shapes", "clutter", "pose", "towers")}
    if too_few := [f"--{name} {value}" for name, value in counts.items() if value < 1]:
        parser.error(f"every section runs at least one episode: {', '.join(too_few)}")
    results = Results(args.out, args.resume)
    for shape in ("cube", "box", "cylinder", "sphere", "capsule"):
        n = args.isolated if shape == "cube" else args.shapes
        r = results.section(f"grasp_{shape}", lambda shape=shape, n=n: isolated_grasps(shape, n))
        print(
            f"planned grasp, isolated {shape:8s}: first attempt {describe_rate(r['first_attempt'])}, within 3 "
            f"{describe_rate(r['within_3'])}; {r['ms_per_attempt_median']:.0f} ms per attempt; {r['failures']}"
        )
    print("    (goal: cubes >= 98 % first, >= 99.5 % within 3; other shapes >= 90 %; <= 100 ms per attempt)")
    r = results.section("grasp_cube_motion_stack", lambda: isolated_grasps("cube", args.pose, "grasp_pose"))
    print(
        f"planned grasp through the motion stack (action_mode='grasp_pose': tolerance IK, RRTConnect, ruckig), "
        f"isolated cubes: first attempt {describe_rate(r['first_attempt'])}, within 3 {describe_rate(r['within_3'])}; "
        f"{r['ms_per_attempt_median']:.0f} ms perception + {r['ms_per_env_step_median']:.0f} ms per env step "
        f"(IK, plan, simulation); {r['failures']}"
    )
    c = results.section("clutter", lambda: clutter(args.clutter))
    print(
        f"planned grasp, clutter of 10: completion {describe_rate(c['completion'])}, grasp success {describe_rate(c['grasp_success'])}, "
        f"action efficiency {100 * c['action_efficiency']:.1f} %, every object grasped {describe_rate(c['every_object_grasped'])}; "
        f"{c['failures']}  (goal: completion >= 95 %, grasp success >= 85 %; VPG 100 / 67.7 / 60.9 %)"
    )
    for oracle in (False, True):
        t = results.section(f"towers_{'oracle' if oracle else 'camera'}", lambda o=oracle: towers(args.towers, o))
        print(
            f"tower builder ({'oracle' if oracle else 'perception'}): success {describe_rate(t['success'])}, "
            f"action efficiency {100 * t['action_efficiency']:.1f} %; {t['failures']}"
            + ("" if oracle else "  (goal >= 95 %, efficiency >= 85 %; SPOT 100 % at 45-51 %)")
        )
    b = results.section("breaking", lambda: breaking(args.towers))
    print(
        f"tower breaker (perception): success {describe_rate(b['success'])}, {b['actions_per_trial']:.2f} actions per trial  (goal >= 99 %)"
    )
    print(f"saved {args.out}")


if __name__ == "__main__":
    main()
