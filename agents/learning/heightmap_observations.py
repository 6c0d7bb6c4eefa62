"""What a heightmap Q-policy sees: the env's ``heightmap`` observation (colour 0-1, height in metres) as uint8
planes -- height in millimetres, and where the policy needs them, whether the hand holds something and the
direction a directional TowerBreak commands -- and the wrapper that hands it to the policy."""

from __future__ import annotations

from typing import Any

import gymnasium as gym
import numpy as np

from panda_grasp_env.tasks.tower_break import BREAK_DIRECTIONS

#: Heights (metres) the uint8 height channel spans: one level per millimetre.
HEIGHT_RANGE = 0.255


def holding_after(info: dict[str, Any]) -> bool:
    """Whether the hand holds something after the step that returned ``info``: its primitive was a grasp
    that succeeded (SPOT's rule; the finger gap cannot tell, since a block grasped across a corner can wedge
    between fully open fingers)."""
    return info.get("primitive") == "grasp" and bool(info.get("primitive_success"))


def command_heading(command: np.ndarray) -> float:
    """World heading (radians) of a directional TowerBreak's one-hot ``command`` (``BREAK_DIRECTIONS`` order)."""
    command = np.asarray(command)
    if command.shape != (len(BREAK_DIRECTIONS),):
        raise ValueError(f"expected a one-hot command of {len(BREAK_DIRECTIONS)} directions, got shape {command.shape}")
    return float(list(BREAK_DIRECTIONS.values())[int(np.argmax(command))])


def encode_heightmap(heightmap: np.ndarray, holding: bool | None = None, heading: float | None = None) -> np.ndarray:
    """Env heightmap (H, W, 4) float32 -- colour 0-1, height metres -- as (4, H, W) uint8 (height in mm);
    with ``holding`` given, a plane that is 255 when the hand holds something, else 0; with a commanded
    world ``heading`` (radians) given, two planes: its cos and sin, mapped from [-1, 1] to 0-254."""
    heightmap = np.asarray(heightmap)
    if heightmap.ndim != 3 or heightmap.shape[-1] != 4:
        raise ValueError(f"expected a (rows, cols, 4) heightmap observation, got shape {heightmap.shape}")
    scaled = heightmap.astype(np.float32)
    scaled[..., 3] = scaled[..., 3] / HEIGHT_RANGE
    planes = [np.round(np.clip(scaled, 0.0, 1.0) * 255).astype(np.uint8).transpose(2, 0, 1)]
    if holding is not None:
        planes.append(np.full((1, *heightmap.shape[:2]), 255 if holding else 0, dtype=np.uint8))
    if heading is not None:
        values = np.round((np.array([np.cos(heading), np.sin(heading)]) + 1.0) * 127.0).astype(np.uint8)
        planes.append(np.broadcast_to(values[:, None, None], (2, *heightmap.shape[:2])))
    return np.ascontiguousarray(np.concatenate(planes))


def encode_observation(observation: Any, info: dict[str, Any], holding_plane: bool) -> np.ndarray:
    """``encode_heightmap`` of an env observation: a bare heightmap, or a dict of ``heightmap`` and
    ``command``; the holding plane (``holding_after`` the step that returned ``info``) if ``holding_plane``."""
    holding = holding_after(info) if holding_plane else None
    if isinstance(observation, dict):
        return encode_heightmap(observation["heightmap"], holding, command_heading(observation["command"]))
    return encode_heightmap(observation, holding)


class EncodedHeightmap(gym.Wrapper):
    """Gives the policy ``encode_observation`` of the env's ``heightmap`` observation (uint8: 4x smaller in
    replay), with the holding plane if ``holding_plane`` and the command planes if the env commands one."""

    def __init__(self, env: gym.Env, holding_plane: bool = False) -> None:
        super().__init__(env)
        space = env.observation_space
        command = isinstance(space, gym.spaces.Dict) and set(space.spaces) == {"heightmap", "command"}
        heightmap = space["heightmap"] if command else space
        if not isinstance(heightmap, gym.spaces.Box) or heightmap.shape[-1:] != (4,) or len(heightmap.shape) != 3:
            raise ValueError(f"EncodedHeightmap needs obs_mode='heightmap' (rows, cols, 4); got {space}")
        rows, cols, _ = heightmap.shape
        self.holding_plane = holding_plane
        channels = 4 + int(holding_plane) + 2 * int(command)
        self.observation_space = gym.spaces.Box(0, 255, (channels, rows, cols), dtype=np.uint8)

    def _encode(self, observation: Any, info: dict[str, Any]) -> np.ndarray:
        return encode_observation(observation, info, self.holding_plane)

    def reset(self, **kwargs: Any) -> tuple[np.ndarray, dict[str, Any]]:
        observation, info = self.env.reset(**kwargs)
        return self._encode(observation, info), info

    def step(self, action: Any) -> tuple[np.ndarray, float, bool, bool, dict[str, Any]]:
        observation, reward, terminated, truncated, info = self.env.step(action)
        return self._encode(observation, info), reward, terminated, truncated, info
