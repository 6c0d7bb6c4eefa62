"""How the workcell is seen: its three cameras (two fixed, one on the hand) and the lights renders see it under.

Nothing here takes part in the physics.  World frame: origin at the robot base on the table top, +x away from
the robot, +z up; metres, degrees for fields of view.  A MuJoCo camera looks along its -z axis, image up +y.
"""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass

import mujoco
import numpy as np

CAMERA_NAMES = ("overhead", "front", "wrist")


@dataclass(frozen=True)
class CameraConfig:
    """A fixed or hand-mounted camera.  ``fovy`` is the vertical field of view in degrees."""

    width: int = 640
    height: int = 480
    fovy: float = 45.0


def look_at(eye: np.ndarray, target: np.ndarray, up: np.ndarray = np.array([0.0, 0.0, 1.0])) -> np.ndarray:
    """Quaternion (w, x, y, z) of a MuJoCo camera at ``eye`` looking at ``target`` (camera looks along -z)."""
    forward = target - eye
    forward /= np.linalg.norm(forward)
    right = np.cross(forward, up)
    right /= np.linalg.norm(right)
    cam_up = np.cross(right, forward)
    rotation = np.column_stack([right, cam_up, -forward])
    quat = np.zeros(4)
    mujoco.mju_mat2Quat(quat, rotation.flatten())
    return quat


def add_wrist_camera(hand: mujoco.MjsBody, cameras: Mapping[str, CameraConfig]) -> None:
    """The ``wrist`` camera on the ``hand`` body (link7), 5 cm off its axis and 11 cm along it, looking along the
    approach direction with image up the hand's +x; field of view from ``cameras["wrist"]`` (default
    ``CameraConfig``)."""
    wrist = hand.add_camera()
    wrist.name = "wrist"
    wrist.pos = [0.05, 0.0, 0.11]
    wrist.quat = [0.0, 0.0, 1.0, 0.0]  # rotate pi about y: look along +z of the hand
    wrist.fovy = cameras.get("wrist", CameraConfig()).fovy


def add_lights(world: mujoco.MjsBody) -> None:
    """Two directional lights from above, in front of the robot; the brighter one casts shadows."""
    for direction, diffuse in (([0.3, 0.3, -1.0], 0.6), ([-0.4, -0.2, -1.0], 0.35)):
        light = world.add_light()
        light.pos = [0.5 - direction[0], -direction[1], 2.0]
        light.dir = direction
        light.diffuse = [diffuse] * 3
        light.specular = [0.1] * 3
        light.castshadow = diffuse > 0.5


def add_fixed_cameras(world: mujoco.MjsBody, cameras: Mapping[str, CameraConfig]) -> None:
    """The ``overhead`` camera 1.05 m above the table looking straight down (image up world +x, the robot at the
    bottom; image right world -y), and the ``front`` camera at (1.25, 0.4, 0.6) looking back at the workspace;
    fields of view from ``cameras`` (default ``CameraConfig``)."""
    overhead = world.add_camera()
    overhead.name = "overhead"
    overhead.pos = [0.45, 0.0, 1.05]
    overhead.quat = [0.70710678, 0.0, 0.0, -0.70710678]
    overhead.fovy = cameras.get("overhead", CameraConfig()).fovy

    front = world.add_camera()
    front.name = "front"
    eye = np.array([1.25, 0.4, 0.6])
    front.pos = eye
    front.quat = look_at(eye, np.array([0.45, 0.0, 0.12]))
    front.fovy = cameras.get("front", CameraConfig()).fovy
