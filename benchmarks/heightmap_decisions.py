"""How long a shipped heightmap DQN takes to decide, on one core, and a fixed set of decisions to test against.

    python benchmarks/heightmap_decisions.py [--repeats 15] [--record] [--observations 200]
                                             [--out results/benchmarks/heightmap_decisions.json]

Timing: for every shipped heightmap checkpoint, ``LearnedAgent.act`` (observation encoding, the Q-network
over all rotations in one batch, the action mask, the arg-max) on the first observation of its env, with
``torch.set_num_threads(1)``; the median of ``--repeats`` decisions after one warm-up.  Goal (issue 29):
<= 30 ms at the shipped resolution.

``--record`` (re)writes ``tests/data/heightmap_decisions.npz``: ``--observations`` encoded heightmaps met
while the shipped policies act in their envs (seeds 0, 1, ..., split across the checkpoints), with the
action each policy chose on each.  ``tests/agents/policies/test_heightmap_decisions.py`` checks that the current code
chooses the very same actions, so a faster Q-network cannot change a decision unnoticed.  Record with the
implementation you want to hold the code to.
"""

from __future__ import annotations

import argparse
import statistics
import sys
import time
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))
import panda_grasp_env  # noqa: E402, F401  (first: it chooses MUJOCO_GL before mujoco is imported)

# isort: split

import torch as th  # noqa: E402

from benchmarks._common import Results, shipped_checkpoints  # noqa: E402
from panda_grasp_env.agents.policies.learned import LearnedAgent  # noqa: E402

RECORDED = ROOT / "tests" / "data" / "heightmap_decisions.npz"
#: Env steps per episode while recording: enough to see towers half built and tables half cleared.
RECORD_STEPS = 8


def time_decisions(name: str, repeats: int) -> dict[str, float]:
    """Median and spread of one checkpoint's decision time (ms) on one core."""
    agent = LearnedAgent(name)
    env = agent.checkpoint.make_env()
    observation, info = env.reset(seed=0)
    agent.reset(observation, info)
    agent.act(observation, info)  # warm-up
    times = []
    for _ in range(repeats):
        start = time.perf_counter()
        agent.act(observation, info)
        times.append((time.perf_counter() - start) * 1e3)
    env.close()
    return {"median_ms": statistics.median(times), "min_ms": min(times), "max_ms": max(times)}


def record(count: int) -> None:
    """Write ``RECORDED``: encoded observations from every shipped heightmap policy's env and its actions."""
    names = shipped_checkpoints(heightmap=True)
    observations: dict[str, list[np.ndarray]] = {name: [] for name in names}
    actions: dict[str, list[int]] = {name: [] for name in names}
    for index, name in enumerate(names):
        wanted = count // len(names) + (index < count % len(names))
        agent = LearnedAgent(name)
        env = agent.checkpoint.make_env()
        seed = 0
        while len(actions[name]) < wanted:
            observation, info = env.reset(seed=seed)
            agent.reset(observation, info)
            for _ in range(RECORD_STEPS):
                observations[name].append(agent.transform(observation, info))
                actions[name].append(int(agent.act(observation, info)))
                observation, _, terminated, truncated, info = env.step(actions[name][-1])
                if terminated or truncated or len(actions[name]) == wanted:
                    break
            seed += 1
        env.close()
        print(f"{name}: {wanted} observations from seeds 0-{seed - 1}")
    arrays = {f"{name}/observations": np.stack(observations[name]) for name in names}
    arrays |= {f"{name}/actions": np.array(actions[name], dtype=np.int64) for name in names}
    RECORDED.parent.mkdir(parents=True, exist_ok=True)
    temporary = RECORDED.with_suffix(".tmp.npz")
    np.savez_compressed(temporary, **arrays)
    temporary.replace(RECORDED)
    print(f"wrote {RECORDED} ({RECORDED.stat().st_size / 1e6:.1f} MB)")


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--repeats", type=int, default=15)
    parser.add_argument("--record", action="store_true", help=f"(re)write {RECORDED.relative_to(ROOT)}")
    parser.add_argument("--observations", type=int, default=200)
    parser.add_argument("--out", type=Path, default=ROOT / "results" / "benchmarks" / "heightmap_decisions.json")
    args = parser.parse_args()
    if args.repeats < 1 or args.observations < 1:
        raise ValueError(f"--repeats and --observations must be >= 1, got {args.repeats}, {args.observations}")
    th.set_num_threads(1)
    if args.record:
        record(args.observations)
        return
    results = Results(args.out, resume=False)
    for name in shipped_checkpoints(heightmap=True):
        figures = results.section(name, lambda name=name: time_decisions(name, args.repeats))
        print(
            f"{name:32s} median {figures['median_ms']:6.1f} ms  (min {figures['min_ms']:.1f}, "
            f"max {figures['max_ms']:.1f}; {args.repeats} decisions, one thread; goal <= 30 ms)"
        )


if __name__ == "__main__":
    main()
