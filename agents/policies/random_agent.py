"""The random baseline: uniformly sampled actions from the env's action space, seeded."""

from __future__ import annotations

from collections import Counter
from typing import Any

import gymnasium as gym
import numpy as np

#: Mixed into the agent's seed so that its actions never replay the env's own draws for the same seed.
ACTION_STREAM = 0x52414E44


class RandomAgent:
    """Samples the action space; the sequence restarts from ``seed`` at every ``reset``.

    The episode's seed usually seeds the env too, and a Gymnasium space seeded with the same integer draws
    the same uniform numbers as the env's scene generator: the first "random" push would start exactly
    where the tower was placed.  The agent therefore samples from a stream derived from (``seed``,
    ``ACTION_STREAM``), independent of the env's.
    """

    name = "random"

    def __init__(self, action_space: gym.Space, seed: int = 0) -> None:
        self.space, self.seed = action_space, seed
        self.failures: Counter[str] = Counter()

    def reset(self, observation: Any, info: dict[str, Any]) -> None:
        self.space.seed(int(np.random.SeedSequence([self.seed, ACTION_STREAM]).generate_state(1)[0]))
        self.failures = Counter()

    def act(self, observation: Any, info: dict[str, Any]) -> Any:
        if "primitive_reason" in info and not info["primitive_success"]:
            self.failures[info["primitive_reason"]] += 1
        return self.space.sample()
