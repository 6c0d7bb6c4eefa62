"""An SB3 model or policy acting through the ``Agent`` protocol (training's evaluations and ``LearnedAgent``)."""

from __future__ import annotations

from collections.abc import Callable
from typing import Any

import numpy as np


class PolicyAgent:
    """An SB3 model or policy as an ``Agent``: deterministic actions from transformed observations.

    With ``avoid_failures`` a policy that makes one (``failure_memory()``: the heightmap Q-policy) also keeps a
    ``FailureMemory``: it does not choose again, within 12 mm and at the same heading, a primitive that failed
    there while the heights around it are unchanged.  Off by default; a checkpoint shipped with it on
    (``Checkpoint.avoid_failures``) had it chosen on selection seeds (``benchmarks/failure_memory.py --seeds
    selection``, docs/learning.md).
    """

    def __init__(
        self, model: Any, transform: Callable[[Any, dict[str, Any]], Any], name: str, avoid_failures: bool = False
    ) -> None:
        self.model, self.transform, self.name = model, transform, name
        self.policy = getattr(model, "policy", model)  # an SB3 model's policy, or the policy itself
        self.memory = None
        if avoid_failures and hasattr(self.policy, "failure_memory"):
            self.memory = self.policy.failure_memory()
        self._chosen: tuple[int, np.ndarray] | None = None  # the last action and what it was chosen on

    def reset(self, observation: Any, info: dict[str, Any]) -> None:
        if self.memory is not None:
            self.memory.reset()
        self._chosen = None

    def act(self, observation: Any, info: dict[str, Any]) -> Any:
        seen = self.transform(observation, info)
        if self.memory is None:
            action, _ = self.model.predict(seen, deterministic=True)
            return action
        if self._chosen is not None and not info.get("primitive_success", True):
            self.memory.record_failure(*self._chosen)
        action = self.policy.greedy_action(seen, self.memory.excluded(seen))
        self._chosen = (action, seen)
        return action
