"""What a heightmap Q-policy sees: the env's ``heightmap`` observation (colour 0-1, height in metres) as uint8
planes -- height in millimetres, and where the policy needs them, whether the hand holds something (and in a
structure task, which kind of piece), the direction a directional TowerBreak commands and the goal heightmap of
a goal-conditioned task -- and the wrapper that hands it to the policy."""

from __future__ import annotations

from typing import Any

import gymnasium as gym
import numpy as np

from panda_grasp_env.tasks.structure_build import GOAL_FIELDS, KIND_CODES
from panda_grasp_env.tasks.tower_break import BREAK_DIRECTIONS

#: Heights (metres) the uint8 height channel spans: one level per millimetre.
HEIGHT_RANGE = 0.255
#: Heights (metres) the uint8 height and goal planes of a goal-conditioned structure observation span: two
#: millimetres per level, so that an eight-cube tower (0.4 m) fits.
GOAL_HEIGHT_RANGE = 0.51


def holding_after(info: dict[str, Any]) -> bool:
    """Whether the hand holds something after the step that returned ``info``: its primitive was a grasp
    that succeeded (SPOT's rule; the finger gap cannot tell, since a block grasped across a corner can wedge
    between fully open fingers)."""
    return info.get("primitive") == "grasp" and bool(info.get("primitive_success"))


def held_slot(info: dict[str, Any]) -> int | None:
    """The object slot the hand holds after the step that returned ``info`` (``holding_after``), or None: the
    slot's index is the number in its body name (``object_<slot>``)."""
    name = str(info.get("primitive_object", ""))
    if not holding_after(info) or not name.startswith("object_") or not name[7:].isdigit():
        return None
    return int(name[7:])


def holding_level(holding: bool, kind_code: int | None = None) -> int:
    """The holding plane's value: 0 for an empty hand; holding, 255, or where the held piece's kind is known
    (``KIND_CODES``), a level above 127 for each kind (cube 170, plank 213, prop 255)."""
    if not holding:
        return 0
    if kind_code is None:
        return 255
    return 128 + round(127 * kind_code / len(KIND_CODES))


def held_kind(achieved_goal: np.ndarray, info: dict[str, Any]) -> int | None:
    """The kind code (``KIND_CODES``) of the piece held after the step that returned ``info``, read from the
    achieved-goal rows of a structure task; None when nothing is held or the slot holds no piece."""
    slot = held_slot(info)
    rows = np.asarray(achieved_goal).reshape(-1, GOAL_FIELDS)
    if slot is None or slot >= len(rows) or int(round(rows[slot, 6])) not in KIND_CODES.values():
        return None
    return int(round(rows[slot, 6]))


def goal_plane(goal: np.ndarray) -> np.ndarray:
    """A goal heightmap ((H, W) or (H, W, 1), metres) as the policy's goal plane: (H, W) uint8 over
    ``GOAL_HEIGHT_RANGE``."""
    goal = np.asarray(goal, dtype=np.float32)
    return np.round(np.clip(goal.reshape(goal.shape[:2]) / GOAL_HEIGHT_RANGE, 0.0, 1.0) * 255).astype(np.uint8)


def command_heading(command: np.ndarray) -> float:
    """World heading (radians) of a directional TowerBreak's one-hot ``command`` (``BREAK_DIRECTIONS`` order)."""
    command = np.asarray(command)
    if command.shape != (len(BREAK_DIRECTIONS),):
        raise ValueError(f"expected a one-hot command of {len(BREAK_DIRECTIONS)} directions, got shape {command.shape}")
    return float(list(BREAK_DIRECTIONS.values())[int(np.argmax(command))])


def encode_heightmap(
    heightmap: np.ndarray,
    holding: bool | int | None = None,
    heading: float | None = None,
    goal: np.ndarray | None = None,
) -> np.ndarray:
    """Env heightmap (H, W, 4) float32 -- colour 0-1, height metres -- as (4, H, W) uint8 (height in mm, or
    with a goal over ``GOAL_HEIGHT_RANGE``); with ``holding`` given, a plane that is 255 when the hand holds something (True), else 0 (or an int: the
    plane's value, ``holding_level``); with a goal heightmap (H, W) or (H, W, 1) metres, a plane of its height
    in mm; with a commanded world ``heading`` (radians) given, two planes last: its cos and sin, mapped from
    [-1, 1] to 0-254."""
    heightmap = np.asarray(heightmap)
    if heightmap.ndim != 3 or heightmap.shape[-1] != 4:
        raise ValueError(f"expected a (rows, cols, 4) heightmap observation, got shape {heightmap.shape}")
    scaled = heightmap.astype(np.float32)
    scaled[..., 3] = scaled[..., 3] / (HEIGHT_RANGE if goal is None else GOAL_HEIGHT_RANGE)
    planes = [np.round(np.clip(scaled, 0.0, 1.0) * 255).astype(np.uint8).transpose(2, 0, 1)]
    if holding is not None:
        level = holding if type(holding) is int else holding_level(bool(holding))
        planes.append(np.full((1, *heightmap.shape[:2]), level, dtype=np.uint8))
    if goal is not None:
        planes.append(goal_plane(goal)[None])
    if heading is not None:
        values = np.round((np.array([np.cos(heading), np.sin(heading)]) + 1.0) * 127.0).astype(np.uint8)
        planes.append(np.broadcast_to(values[:, None, None], (2, *heightmap.shape[:2])))
    return np.ascontiguousarray(np.concatenate(planes))


def encode_observation(observation: Any, info: dict[str, Any], holding_plane: bool) -> np.ndarray:
    """``encode_heightmap`` of an env observation: a bare heightmap, a dict of ``heightmap`` and ``command``, or a
    goal-conditioned structure task's dict (``heightmap``, ``goal_heightmap``, ``achieved_goal``, ...); the
    holding plane (``holding_after`` the step that returned ``info``; in a structure task, the held kind's
    ``holding_level``) if ``holding_plane``."""
    holding = holding_after(info) if holding_plane else None
    if not isinstance(observation, dict):
        return encode_heightmap(observation, holding)
    if "goal_heightmap" in observation:
        if holding:
            holding = holding_level(True, held_kind(observation["achieved_goal"], info))
        return encode_heightmap(observation["heightmap"], holding, goal=observation["goal_heightmap"])
    return encode_heightmap(observation["heightmap"], holding, command_heading(observation["command"]))


class EncodedHeightmap(gym.Wrapper):
    """Gives the policy ``encode_observation`` of the env's ``heightmap`` observation (uint8: 4x smaller in
    replay), with the holding plane if ``holding_plane``, the command planes if the env commands one and the
    goal plane if it is goal-conditioned on a goal heightmap."""

    def __init__(self, env: gym.Env, holding_plane: bool = False) -> None:
        super().__init__(env)
        space = env.observation_space
        entries = set(getattr(space, "spaces", {}))
        command = entries == {"heightmap", "command"}
        goal = {"heightmap", "goal_heightmap", "achieved_goal"} <= entries
        heightmap = space["heightmap"] if command or goal else space
        if not isinstance(heightmap, gym.spaces.Box) or heightmap.shape[-1:] != (4,) or len(heightmap.shape) != 3:
            raise ValueError(f"EncodedHeightmap needs obs_mode='heightmap' (rows, cols, 4); got {space}")
        rows, cols, _ = heightmap.shape
        self.holding_plane = holding_plane
        channels = 4 + int(holding_plane) + int(goal) + 2 * int(command)
        self.observation_space = gym.spaces.Box(0, 255, (channels, rows, cols), dtype=np.uint8)

    def _encode(self, observation: Any, info: dict[str, Any]) -> np.ndarray:
        return encode_observation(observation, info, self.holding_plane)

    def reset(self, **kwargs: Any) -> tuple[np.ndarray, dict[str, Any]]:
        observation, info = self.env.reset(**kwargs)
        return self._encode(observation, info), info

    def step(self, action: Any) -> tuple[np.ndarray, float, bool, bool, dict[str, Any]]:
        observation, reward, terminated, truncated, info = self.env.step(action)
        return self._encode(observation, info), reward, terminated, truncated, info
