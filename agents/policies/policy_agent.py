"""An SB3 model or policy acting through the ``Agent`` protocol (training's evaluations and ``LearnedAgent``)."""

from __future__ import annotations

from collections.abc import Callable, Mapping
from typing import Any

import numpy as np

#: The rules a checkpoint can act by (``PolicyAgent``'s keyword arguments, ``checkpoint.json``'s keys), as its
#: card names them.
ACTING_RULES = {
    "avoid_failures": "its `FailureMemory`",
    "centre_on_faces": "`FaceCentring`",
    "inward_pushes": "`InwardPushes`",
    "place_where_lacking": "`LackingPlaces`",
}


def check_acting_rules(acting: Mapping[str, bool]) -> None:
    """``ValueError`` naming any key of ``acting`` that is not one of ``ACTING_RULES``."""
    unknown = sorted(set(acting) - set(ACTING_RULES))
    if unknown:
        raise ValueError(f"unknown acting rules {unknown}; known: {list(ACTING_RULES)}")


class PolicyAgent:
    """An SB3 model or policy as an ``Agent``: deterministic actions from transformed observations.

    A heightmap Q-policy can also act by rules chosen on selection seeds (``agents/learning/acting_rules.py``),
    each off by default and shipped on where chosen (``Checkpoint.acting``):

    * ``avoid_failures``: it keeps a ``FailureMemory``: it does not choose again, within 12 mm and at the same
      heading, a primitive that failed there while the heights around it are unchanged
      (``benchmarks/failure_memory.py --seeds selection``, docs/learning.md);
    * ``centre_on_faces``: ``FaceCentring`` moves its grasps and places onto the centre of the block face
      chosen, and places on a tower onto the tower's axis (docs/tall-towers.md);
    * ``inward_pushes``: ``InwardPushes`` forbids pushes that would topple a tower away from the heightmap's
      middle (``build_and_break_dqn``'s breaker acts with it);
    * ``place_where_lacking``: ``LackingPlaces`` lets a goal-conditioned policy place only where the goal
      heightmap stands above the scene's (``benchmarks/builder_failures.py --place-where-lacking``).
    """

    def __init__(
        self,
        model: Any,
        transform: Callable[[Any, dict[str, Any]], Any],
        name: str,
        avoid_failures: bool = False,
        centre_on_faces: bool = False,
        inward_pushes: bool = False,
        place_where_lacking: bool = False,
    ) -> None:
        self.model, self.transform, self.name = model, transform, name
        self.policy = getattr(model, "policy", model)  # an SB3 model's policy, or the policy itself
        self.memory = None
        if avoid_failures and hasattr(self.policy, "failure_memory"):
            self.memory = self.policy.failure_memory()
        self.centre_on_faces = centre_on_faces and hasattr(self.policy, "face_centring")
        self.centring = None  # made at reset, for the episode's block size
        self.facts: dict[str, Any] = {}  # the env's reset facts FaceCentring reads (block_size, action_layout)
        self.inward = self.policy.inward_pushes() if inward_pushes and hasattr(self.policy, "inward_pushes") else None
        self.lacking = (
            self.policy.lacking_places() if place_where_lacking and hasattr(self.policy, "lacking_places") else None
        )
        self._chosen: tuple[int, np.ndarray] | None = None  # the last action and what it was chosen on

    def reset(self, observation: Any, info: dict[str, Any]) -> None:
        if self.memory is not None:
            self.memory.reset()
        if self.centre_on_faces:
            # The env's reset info gives the blocks' size and the action grid; a reset mid-episode (a phase's,
            # on a step's info) keeps them.  A tower task's info gives its base's centre at each build's start.
            self.facts |= {key: info[key] for key in ("block_size", "action_layout") if key in info}
            if "block_size" not in self.facts:
                raise ValueError(f"{self.name} centres on block faces, but the env's reset info has no block_size")
            base = info.get("base_position") if "action_layout" in self.facts else None
            self.centring = self.policy.face_centring(
                float(self.facts["block_size"]), base, self.facts.get("action_layout")
            )
        self._chosen = None

    def act(self, observation: Any, info: dict[str, Any]) -> Any:
        seen = self.transform(observation, info)
        if self.memory is None and self.centring is None and self.inward is None and self.lacking is None:
            action, _ = self.model.predict(seen, deterministic=True)
            return action
        excluded = None if self.inward is None else self.inward.excluded()
        if self.lacking is not None:
            lacking = self.lacking.excluded(seen)
            excluded = lacking if excluded is None else excluded | lacking
        if self.memory is not None:
            if self._chosen is not None and not info.get("primitive_success", True):
                self.memory.record_failure(*self._chosen)
            remembered = self.memory.excluded(seen)
            if remembered is not None:
                excluded = remembered if excluded is None else excluded | remembered
        action = self.policy.greedy_action(seen, excluded)
        if self.centring is not None:
            action = self.centring.centred(action, seen)
        self._chosen = (action, seen)
        return action
