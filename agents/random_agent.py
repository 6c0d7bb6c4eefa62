"""The random baseline: uniformly sampled actions from the env's action space, seeded."""

from __future__ import annotations

from collections import Counter
from typing import Any

import gymnasium as gym


class RandomAgent:
    """Samples the action space; the sequence restarts from ``seed`` at every ``reset``."""

    name = "random"

    def __init__(self, action_space: gym.Space, seed: int = 0) -> None:
        self.space, self.seed = action_space, seed
        self.failures: Counter[str] = Counter()

    def reset(self, observation: Any, info: dict[str, Any]) -> None:
        self.space.seed(self.seed)
        self.failures = Counter()

    def act(self, observation: Any, info: dict[str, Any]) -> Any:
        if "primitive_reason" in info and not info["primitive_success"]:
            self.failures[info["primitive_reason"]] += 1
        return self.space.sample()
