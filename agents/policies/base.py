"""The agent protocol and what every agent shares: reading observations, building actions, counting failures.

An agent sees what the env gives every learner -- the observation and the
``info`` dict, including the facts ``reset`` publishes (``camera_models``,
``block_colours``, ``block_size``, ``action_layout``) -- and nothing else.  The
exception says so in its name: ``Oracle*`` perceivers read the simulator's
true poses, to separate perception failures from the rest.
"""

from __future__ import annotations

from collections import Counter
from typing import Any, Protocol

import numpy as np

from panda_grasp_env.actions import encode_primitive
from panda_grasp_env.perception.heightmap import HeightmapGrid
from panda_grasp_env.perception.noise import DepthNoise, RGBNoise
from panda_grasp_env.perception.pose import View

#: Failure categories agents report (``Agent.failures``), on top of the env's primitive reasons.
FAILURES = (
    "no_candidate",
    "no_ik_solution",
    "no_plan",
    "collision",
    "missed",
    "dropped",
    "placed_off",
    "tower_fell",
    "unreachable",
    "out_of_workspace",
    "not_holding",
)


class Agent(Protocol):
    """Chooses actions from observations: ``reset`` once per episode, then ``act`` every step."""

    name: str

    def reset(self, observation: Any, info: dict[str, Any]) -> None: ...

    def act(self, observation: Any, info: dict[str, Any]) -> Any: ...


def require(info: dict[str, Any], keys: tuple[str, ...], agent: str, hint: str) -> None:
    """Raise ``ValueError`` at reset if the env does not publish what the agent needs."""
    missing = [k for k in keys if k not in info]
    if missing:
        raise ValueError(f"{agent} needs {missing} in the reset info; {hint}")


class PrimitiveActionWriter:
    """Builds actions from world coordinates using the layout the env published: a ``primitive``-mode action,
    or in ``pixel`` mode the index of the heightmap cell under (x, y) at the nearest of the env's headings
    (VPG's discrete actions; the env then chooses the heights, so ``needs_z`` asks nothing of it)."""

    def __init__(self, info: dict[str, Any], agent: str, needs: tuple[str, ...], needs_z: bool = False) -> None:
        require(info, ("action_layout",), agent, "make the env with action_mode='primitive'")
        layout = info["action_layout"]
        if layout["mode"] not in ("primitive", "pixel"):
            raise ValueError(
                f"{agent} writes primitive actions: make the env with action_mode='primitive' (or "
                f"'pixel'), not {layout['mode']!r}"
            )
        missing = [p for p in needs if p not in layout["primitives"]]
        if missing:
            raise ValueError(f"{agent} needs the primitives {missing}; this env offers {layout['primitives']}")
        self.primitives = tuple(layout["primitives"])
        self.pixel_shape: tuple[int, ...] | None = None
        if layout["mode"] == "pixel":
            self.pixel_shape = tuple(layout["shape"])  # (primitive, rotation, row, column)
            self.grid = HeightmapGrid.of_layout(layout)
            self.with_z = False
            return
        if needs_z and not layout["primitive_z"]:
            raise ValueError(f"{agent} chooses grasp heights itself: make the env with primitive_z=True")
        self.with_z = bool(layout["primitive_z"])

    def __call__(self, name: str, x: float, y: float, yaw: float, z: float | None = None) -> np.ndarray:
        """The action running primitive ``name`` at world (x, y[, z]) metres with heading ``yaw`` radians."""
        if self.pixel_shape is None:
            return encode_primitive(self.primitives, self.with_z, name, x, y, yaw, z if self.with_z else None)
        if name not in self.primitives:
            raise ValueError(f"primitive {name!r} not available here; valid: {list(self.primitives)}")
        _, rotations, rows, cols = self.pixel_shape
        row, col = (int(i) for i in self.grid.world_to_cell(np.array([x, y])))
        if not (0 <= row < rows and 0 <= col < cols):
            raise ValueError(
                f"({x:.3f}, {y:.3f}) m lies outside the heightmap the pixel actions cover ({self.grid.bounds[:2]})"
            )
        rotation = int(np.round(yaw / (2 * np.pi / rotations))) % rotations
        return np.array(np.ravel_multi_index((self.primitives.index(name), rotation, row, col), self.pixel_shape))


class CameraViews:
    """Reads (RGB, depth) per camera out of observations, optionally through the sensor noise model."""

    def __init__(
        self, observation: Any, info: dict[str, Any], agent: str, cameras: tuple[str, ...], noise_seed: int | None
    ) -> None:
        require(info, ("camera_models",), agent, "use an env from panda_grasp_env")
        available = info["camera_models"]
        missing = [c for c in cameras if c not in available]
        if missing:
            raise ValueError(
                f"{agent} needs images from cameras {missing}: make the env with obs_mode='rgbd' and "
                f"cameras={cameras} (it has {list(available)})"
            )
        self.models = {c: available[c] for c in cameras}
        self.single = len(available) == 1
        if not isinstance(observation, dict):
            raise ValueError(f"{agent} needs a Dict observation with RGB and depth images (obs_mode='rgbd')")
        missing_keys = [
            k for c in cameras for k in (self._key(c, "rgb"), self._key(c, "depth")) if k not in observation
        ]
        if missing_keys:
            raise ValueError(f"{agent} needs observation keys {missing_keys}: make the env with obs_mode='rgbd'")
        self.rng = None if noise_seed is None else np.random.default_rng(noise_seed)

    def _key(self, camera: str, modality: str) -> str:
        return modality if self.single else f"{camera}_{modality}"

    def __call__(self, observation: dict[str, np.ndarray]) -> list[View]:
        views = []
        for camera, model in self.models.items():
            rgb = observation[self._key(camera, "rgb")]
            depth = observation[self._key(camera, "depth")][..., 0]
            if self.rng is not None:
                rgb, depth = RGBNoise().apply(rgb, self.rng), DepthNoise().apply(depth, self.rng)
            views.append(View(rgb, depth, model))
        return views


def record_failure(failures: Counter, info: dict[str, Any]) -> None:
    """Count the last primitive's failure reason (if it failed)."""
    if "primitive_reason" in info and not info["primitive_success"]:
        failures[info["primitive_reason"]] += 1
