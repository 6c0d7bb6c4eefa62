"""``EnvOptions``: ``PandaEnv``'s options, checked before anything is built.

Every bad value raises a ``ValueError`` that names its option (``PandaEnv``'s docstring describes each).
"""

from __future__ import annotations

from dataclasses import dataclass, replace
from typing import Any

import mujoco
import numpy as np

from panda_grasp_env.actions import ACTION_MODES, ActionMode
from panda_grasp_env.geometry import is_number
from panda_grasp_env.model.scene import CAMERA_NAMES, PRIMITIVE_NOSLIP_ITERATIONS, SceneConfig
from panda_grasp_env.observations import parse_obs_mode
from panda_grasp_env.perception.heightmap import HeightmapGrid
from panda_grasp_env.randomization import Randomization
from panda_grasp_env.sim.rendering import RENDER_MODES, advertised_render_modes, display_available
from panda_grasp_env.tasks import REWARD_TYPES, Task

#: Largest image or render side, pixels.
MAX_IMAGE_SIDE = 2048
#: Most headings of the ``pixel`` action mode (VPG uses 16).
MAX_ROTATIONS = 64
#: A heightmap grid has this many cells per side, at least and at most.
GRID_SIDES = (16, 1024)


def checked_cameras(cameras: Any) -> tuple[str, ...]:
    """``cameras`` (one name or a sequence of names) as a tuple; ``ValueError`` unless they are known and distinct."""
    names = (cameras,) if isinstance(cameras, str) else tuple(cameras) if isinstance(cameras, (tuple, list)) else None
    if not names or not all(isinstance(c, str) and c in CAMERA_NAMES for c in names) or len(set(names)) < len(names):
        raise ValueError(f"cameras must be distinct names from {list(CAMERA_NAMES)}, got {cameras!r}")
    return names


def checked_size(name: str, size: Any) -> tuple[int, int]:
    """``size`` as (width, height) pixels, each an int from 1 to ``MAX_IMAGE_SIDE``; else ``ValueError``."""
    sides = tuple(size) if isinstance(size, (tuple, list, np.ndarray)) else ()
    whole = all(isinstance(v, (int, np.integer)) and not isinstance(v, bool) for v in sides)
    if len(sides) != 2 or not whole or not all(1 <= v <= MAX_IMAGE_SIDE for v in sides):
        raise ValueError(f"{name} must be (width, height) in ints from 1 to {MAX_IMAGE_SIDE}, got {size!r}")
    return int(sides[0]), int(sides[1])


def checked_start_curriculum(requested: dict[str, Any], mode: type[ActionMode], task: Task) -> dict[str, float]:
    """The ``start_*`` probabilities that are not zero, by start state, after checking them: each in [0, 1],
    together at most 1, and only for a low-level ``mode`` and a task that can start in that state."""
    for state, value in requested.items():
        name = f"start_{state}"
        if not (is_number(value) and 0.0 <= value <= 1.0):
            raise ValueError(f"{name} must be a probability in [0, 1], got {value!r}")
        if value and not (mode.low_level and state in task.start_states):
            raise ValueError(
                f"{name} needs a low-level action mode (ee_delta, joint) and a task that can start "
                f"{state.replace('_', ' ')}; got action_mode={mode.name!r}, task={task.name!r} "
                f"(its start states: {list(task.start_states)})"
            )
    if sum(requested.values()) > 1.0:
        raise ValueError(f"the start_* probabilities must sum to <= 1, got {sum(requested.values())}")
    return {state: float(value) for state, value in requested.items() if value}


def checked_grid(bounds: Any, resolution: Any) -> HeightmapGrid:
    """The heightmap grid of ``heightmap_bounds`` (metres) and ``heightmap_resolution`` (metres per cell);
    ``ValueError`` unless it has ``GRID_SIDES`` cells per side."""
    if not (is_number(resolution) and resolution > 0):
        raise ValueError(f"heightmap_resolution must be a positive number of metres, got {resolution!r}")
    try:
        grid = HeightmapGrid(tuple(map(tuple, bounds)), float(resolution))
    except (TypeError, ValueError):
        raise ValueError(f"heightmap_bounds must be ((x0, x1), (y0, y1), (z0, z1)) metres, got {bounds!r}") from None
    low, high = GRID_SIDES
    if not all(low <= side <= high for side in grid.shape):
        raise ValueError(
            f"heightmap_resolution={resolution!r} over heightmap_bounds={bounds!r} gives a {grid.shape} grid; "
            f"each side must have {low}-{high} cells"
        )
    return grid


@dataclass(frozen=True)
class EnvOptions:
    """``PandaEnv``'s options for one task, checked and in their working forms (pixels, metres)."""

    obs_mode: str
    #: The parts of ``obs_mode``.
    modalities: tuple[str, ...]
    #: The action mode's name: the one given, or the task's default.
    action_mode: str
    render_mode: str | None
    cameras: tuple[str, ...]
    #: (width, height) pixels, as ``render_size``.
    image_size: tuple[int, int]
    #: ``heightmap_bounds`` at ``heightmap_resolution``.
    grid: HeightmapGrid
    rotations: int
    primitive_z: bool
    push_distance: float
    block_gripper: bool
    render_size: tuple[int, int]
    planner: str
    scene: SceneConfig | None
    #: Start state -> probability of an episode starting there (a training curriculum; empty: none).
    start_curriculum: dict[str, float]
    randomization: Randomization | None
    reward_type: str
    #: Whether the agent sees and is rewarded by goals: a goal-conditioned task in a low-level mode.
    goal_conditioned: bool

    @property
    def mode(self) -> type[ActionMode]:
        """The action mode's class."""
        return ACTION_MODES[self.action_mode]

    def scene_config(self, task: Task) -> SceneConfig:
        """The workcell's scene: ``scene`` (or the defaults) as ``task`` sets it, with the task's fixtures after
        those of ``scene`` (if any)."""
        # Low-level modes: no noslip pass unless the scene sets one.  It stops a held block creeping in the
        # fingers during long primitive carries (place accuracy); at 25 Hz control it costs ~10 % of the rate.
        base = self.scene or SceneConfig()
        if base.noslip_iterations is None:
            base = replace(base, noslip_iterations=0 if self.mode.low_level else PRIMITIVE_NOSLIP_ITERATIONS)
        config = task.scene_config(base)
        given = config.fixtures
        if given is None:
            return replace(config, fixtures=task.add_fixtures)

        def both(spec: mujoco.MjSpec) -> None:
            given(spec)
            task.add_fixtures(spec)

        return replace(config, fixtures=both)

    @classmethod
    def checked(
        cls,
        task: Task,
        *,
        obs_mode: Any,
        action_mode: Any,
        render_mode: Any,
        cameras: Any,
        image_size: Any,
        heightmap_resolution: Any,
        heightmap_bounds: Any,
        rotations: Any,
        primitive_z: Any,
        push_distance: Any,
        block_gripper: Any,
        render_size: Any,
        planner: Any,
        scene: Any,
        start_in_hand: Any,
        start_above_object: Any,
        start_behind_object: Any,
        randomization: Any,
        reward_type: Any,
    ) -> EnvOptions:
        """The options of ``PandaEnv`` (same names) for ``task``; ``ValueError`` naming the first bad one."""
        action_mode = task.default_action_mode if action_mode is None else action_mode
        if not isinstance(action_mode, str) or action_mode not in ACTION_MODES:
            raise ValueError(f"unknown action_mode {action_mode!r}; valid: {list(ACTION_MODES)}")
        mode = ACTION_MODES[action_mode]
        if render_mode == "human" and not display_available():
            raise ValueError("render_mode='human' needs a display (neither DISPLAY nor WAYLAND_DISPLAY is set); "
                             "use 'rgb_array' and save the frames, e.g. with gymnasium's RecordVideo")  # fmt: skip
        if render_mode is not None and render_mode not in RENDER_MODES:
            raise ValueError(f"unknown render_mode {render_mode!r}; valid: {advertised_render_modes()} or None")
        cameras = checked_cameras(cameras)
        image_size, render_size = checked_size("image_size", image_size), checked_size("render_size", render_size)
        if scene is not None and not isinstance(scene, SceneConfig):
            raise ValueError(
                f"scene must be a panda_grasp_env.model.scene.SceneConfig or None, got {type(scene).__name__}"
            )
        for name, flag in (("primitive_z", primitive_z), ("block_gripper", block_gripper)):
            if not isinstance(flag, (bool, np.bool_)):
                raise ValueError(f"{name} must be a bool, got {flag!r}")
        if not (isinstance(rotations, (int, np.integer)) and not isinstance(rotations, bool)
                and 1 <= rotations <= MAX_ROTATIONS):  # fmt: skip
            raise ValueError(f"rotations must be an int from 1 to {MAX_ROTATIONS}, got {rotations!r}")
        if not isinstance(planner, str):
            raise ValueError(f"planner must be an OMPL planner's name (a str), got {planner!r}")
        if block_gripper and action_mode != "ee_delta":
            raise ValueError(f"block_gripper=True needs action_mode='ee_delta', not {action_mode!r}")
        if not (is_number(push_distance) and 0 < push_distance <= 0.3):
            raise ValueError(f"push_distance must be in (0, 0.3] m, got {push_distance!r}")
        randomization = Randomization.of(randomization)
        modalities = parse_obs_mode(obs_mode)
        grid = checked_grid(heightmap_bounds, heightmap_resolution)
        requested = {"in_hand": start_in_hand, "above_object": start_above_object, "behind_object": start_behind_object}
        start_curriculum = checked_start_curriculum(requested, mode, task)
        goal_conditioned = mode.low_level and task.goal_conditioned
        if reward_type not in REWARD_TYPES:
            raise ValueError(f"unknown reward_type {reward_type!r}; valid: {list(REWARD_TYPES)}")
        if reward_type == "dense" and not goal_conditioned:
            raise ValueError(f"reward_type='dense' is the goal distance of a goal-conditioned task in a low-level "
                             f"action mode; {task.name!r} in {action_mode!r} mode has no goal reward to make dense")  # fmt: skip
        return cls(obs_mode, modalities, action_mode, render_mode, cameras, image_size, grid, int(rotations),
                   bool(primitive_z), push_distance, bool(block_gripper), render_size, planner, scene,
                   start_curriculum, randomization, reward_type, goal_conditioned)  # fmt: skip
