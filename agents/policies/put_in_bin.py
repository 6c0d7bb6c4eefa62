"""The PutInBin baseline: grasp the named block where perception sees it, place it in the middle of the bin.

With ``CameraBlocks`` (the planned agent) the block is found in the env's RGB-D images; with
``OracleBlocks`` its true pose is read from the simulator.  Acts through the ``primitive`` action mode.
World frame, metres, radians.
"""

from __future__ import annotations

from collections import Counter
from typing import Any

import numpy as np

from panda_grasp_env.agents.policies.base import PrimitiveActionWriter, record_failure, require
from panda_grasp_env.agents.policies.registry import register_baseline
from panda_grasp_env.agents.policies.towers import CameraBlocks, OracleBlocks, block_baseline
from panda_grasp_env.sim.stacking import clearest_grasp_heading


class PutInBinAgent:
    """Grasp the target block (the heading pointing least at the other blocks), then place it at the
    bin's centre with the same heading; after a failed grasp or place, try again from what it sees."""

    def __init__(self, perceiver: CameraBlocks | OracleBlocks | None = None) -> None:
        self.perceiver = perceiver or CameraBlocks()
        self.name = f"put_in_bin_{self.perceiver.name}"
        self.failures: Counter[str] = Counter()

    def reset(self, observation: Any, info: dict[str, Any]) -> None:
        require(info, ("target", "bin_position"), self.name, "use PandaPutInBin-v0")
        self.write = PrimitiveActionWriter(info, self.name, ("grasp", "place"))
        self.perceiver.reset(observation, info, self.name)
        self.target, self.bin_position = info["target"], np.asarray(info["bin_position"], dtype=float)
        self.holding_heading: float | None = None  # the grasp heading while the target is in the hand
        self.pending_heading: float | None = None
        self.failures = Counter()

    def act(self, observation: Any, info: dict[str, Any]) -> np.ndarray:
        record_failure(self.failures, info)
        if info.get("primitive") == "grasp":
            self.holding_heading = self.pending_heading if info["primitive_success"] else None
        elif info.get("primitive") == "place":
            self.holding_heading = None
        if self.holding_heading is not None:
            x, y = self.bin_position[:2]
            return self.write("place", x, y, self.holding_heading)
        blocks = self.perceiver(observation)
        if self.target not in blocks:
            self.failures["no_candidate"] += 1
            return self.write("grasp", 0.3, -0.3, 0.0, 0.02)  # nothing sensible: a harmless miss
        names = list(blocks)
        positions = np.array([blocks[n].position for n in names])
        block = blocks[self.target]
        self.pending_heading = clearest_grasp_heading(positions, names.index(self.target), block.yaw)
        return self.write("grasp", block.position[0], block.position[1], self.pending_heading, block.position[2])


register_baseline("PutInBin")(block_baseline(PutInBinAgent))
