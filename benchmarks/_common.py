"""Shared helpers for the benchmark scripts: medians, atomic JSON results, resumable sections."""

from __future__ import annotations

import argparse
import json
import os
import platform
import statistics
import sys
import time
from collections.abc import Callable
from pathlib import Path
from typing import Any

import numpy as np
import torch as th

from panda_grasp_env.agents.evaluation.metrics import clustered_rate, describe_rate, rate, wilson  # noqa: F401  (one implementation each)
from panda_grasp_env.agents.learning.config import HEIGHTMAP_ALGORITHMS
from panda_grasp_env.agents.policies.learned import Checkpoint, available_checkpoints
from panda_grasp_env.tooling.runs import machine as machine_name
from panda_grasp_env.tooling.runs import write_atomically

sys.stdout.reconfigure(line_buffering=True)  # figures appear as they are measured, even when piped


def median_rate(run: Callable[[], int], repeats: int = 5) -> float:
    """Median of ``repeats`` measurements of ``run()``'s count per wall-clock second."""
    rates = []
    for _ in range(repeats):
        start = time.perf_counter()
        count = run()
        rates.append(count / (time.perf_counter() - start))
    return statistics.median(rates)


#: The columns ``policy_row`` prints, after the caller's own.
POLICY_COLUMNS = (
    f"{'N':>4} {'success (95 % CI)':<24} {'completion':>10} {'grasp success':>16} {'efficiency':>10}  failures"
)


def policy_row(figures: dict[str, Any]) -> str:
    """``policy_figures`` as one printed line under ``POLICY_COLUMNS``."""
    success, grasp = figures["trial_success"], figures["grasp_success"]
    low, high = success["ci95"]
    return (
        f"{figures['episodes']:>4} {success['rate']:>6.1%} ({low:.1%}-{high:.1%}){'':<4} "
        f"{figures['completion']['rate']:>10.1%} {grasp['rate']:>7.1%} ({grasp['successes']}/{grasp['n']}) "
        f"{figures['action_efficiency']:>10.1%}  {figures['failures']}"
    )


def policy_figures(metrics: dict[str, Any]) -> dict[str, Any]:
    """The task figures a policy benchmark saves from ``panda_grasp_env.agents.evaluation.metrics.aggregate``'s metrics."""
    keys = ("trial_success", "completion", "grasp_success", "action_efficiency", "failures", "episodes", "seeds")
    return {key: metrics[key] for key in keys}


def check_selection_episodes(parser: argparse.ArgumentParser, episodes: int) -> None:
    """``parser.error`` unless ``episodes`` episodes from the selection seeds stay clear of the test seeds."""
    from panda_grasp_env.agents.learning.config import MOST_SELECTION_EPISODES

    if not 1 <= episodes <= MOST_SELECTION_EPISODES:
        parser.error(f"--episodes must be in [1, {MOST_SELECTION_EPISODES}] (clear of the test seeds)")


def shipped_checkpoints(heightmap: bool) -> list[str]:
    """Names of the shipped heightmap (pixel-action DQN) checkpoints, or of the low-level ones."""
    names = available_checkpoints()
    return [name for name in names if (Checkpoint(name).config.algo in HEIGHTMAP_ALGORITHMS) == heightmap]


def machine() -> dict[str, Any]:
    import mujoco

    return {
        "python": platform.python_version(),
        "mujoco": mujoco.__version__,
        "cpus": os.cpu_count(),
        "machine": machine_name(),
    }


class Results:
    """Sections of a benchmark saved to one JSON file, atomically after each section; ``resume`` skips finished ones."""

    def __init__(self, path: Path, resume: bool) -> None:
        self.path = path
        self.data: dict[str, Any] = json.loads(path.read_text()) if resume and path.exists() else {}
        self.data["machine"] = machine()

    def section(self, name: str, compute: Callable[[], dict[str, Any]]) -> dict[str, Any]:
        if name not in self.data:
            self.data[name] = compute()
            self.path.parent.mkdir(parents=True, exist_ok=True)
            write_atomically(self.path, json.dumps(self.data, indent=2))
        return self.data[name]


class RandomChoice:
    """A heightmap Q-policy's masks and acting rules with a seeded uniformly random allowed action in place of
    its best (``greedy_action``); everything else is the wrapped policy's."""

    def __init__(self, policy: Any, seed: int) -> None:
        self.inner, self.rng = policy, np.random.default_rng(seed)

    def greedy_action(self, observation: np.ndarray, excluded: np.ndarray | None = None) -> int:
        with th.no_grad():
            allowed = self.inner.q_net.allowed(th.as_tensor(observation[None])).numpy()[0]
        if excluded is not None and (allowed & ~excluded).any():
            allowed &= ~excluded
        return int(self.rng.choice(np.flatnonzero(allowed)))

    def __getattr__(self, name: str) -> Any:
        return getattr(self.inner, name)
