"""Observations: state vectors, camera images and heightmaps, rendered at most once per env step.

``obs_mode`` is one modality or several joined with ``+`` (``"rgb+depth"``,
``"state+heightmap"``; ``"rgbd"`` means ``"rgb+depth"``):

* ``state`` -- float32 vector (see ``state_layout``): robot, then every object slot, then the task's
  ``properties`` (if any) and, in primitive modes of goal tasks, the goal;
* ``proprio`` -- the robot's part of the state alone (``ROBOT_STATE_SIZE`` entries: nothing about the
  objects), for policies that must see the objects through cameras;
* ``rgb`` -- (H, W, 3) uint8; ``depth`` -- (H, W, 1) float32 metres along the
  optical axis; ``segmentation`` -- (H, W, 1) uint8 labels: 0 background
  (table, floor), 1 robot, 2 + i object slot i (blocks first);
* ``heightmap`` -- (rows, cols, 4) float32: colour in 0-1 and height in metres
  above the table, VPG-style, projected from the overhead camera's RGB-D; a goal-conditioned env whose
  task draws its goal (the structures) adds ``goal_heightmap`` (rows, cols, 1): the goal's heights, metres.

One modality gives a bare ``Box``; several give a ``Dict``, and so does a task
with a command (the directional TowerBreak's one-hot ``command``).  Goal-conditioned
low-level envs always give a ``Dict`` with ``achieved_goal`` and
``desired_goal``, plus ``observation`` (the state) when ``state`` is asked for,
plus any image keys.  Image keys are
the modality name, or ``<camera>_<modality>`` when several cameras are used.
"""

from __future__ import annotations

import math
from collections.abc import Callable
from typing import Any

import gymnasium as gym
import mujoco
import numpy as np

from panda_grasp_env.model.robot import fast_index
from panda_grasp_env.perception.camera import CameraModel
from panda_grasp_env.perception.heightmap import HeightmapGrid, heightmap_from_rgbd
from panda_grasp_env.sim.rendering import CameraRenderer
from panda_grasp_env.sim.workcell import Workcell

MODALITIES = ("state", "proprio", "rgb", "depth", "segmentation", "heightmap")
IMAGE_MODALITIES = ("rgb", "depth", "segmentation")
#: Camera whose RGB-D the heightmap is projected from, and its resolution (a Kinect's).
HEIGHTMAP_CAMERA = ("overhead", 640, 480)
#: State and goal entries are clipped to +- this (positions are within metres of the origin;
#: anything faster than 100 m/s or rad/s has diverged anyway).
STATE_BOUND = 100.0
ROBOT_STATE_SIZE = 23
OBJECT_STATE_SIZE = 14


def bounded(values: np.ndarray) -> np.ndarray:
    """float32 copy clipped to +- ``STATE_BOUND``."""
    return np.minimum(np.maximum(values, -STATE_BOUND), STATE_BOUND).astype(np.float32)


def parse_obs_mode(obs_mode: str) -> tuple[str, ...]:
    """Modalities of an ``obs_mode`` string; ``ValueError`` listing the valid ones if unknown, or naming a
    part given twice (as duplicate cameras are refused)."""
    if not isinstance(obs_mode, str) or not obs_mode:
        raise ValueError(f"obs_mode must be a non-empty string, got {obs_mode!r}; valid modalities: {list(MODALITIES)}")
    parts: list[str] = []
    for part in obs_mode.replace("rgbd", "rgb+depth").split("+"):
        if part not in MODALITIES:
            raise ValueError(f"unknown obs_mode part {part!r} in {obs_mode!r}; valid: {list(MODALITIES)} or 'rgbd'")
        if part in parts:
            raise ValueError(f"obs_mode part {part!r} appears twice in {obs_mode!r} (rgbd is rgb+depth)")
        parts.append(part)
    return tuple(parts)


def state_layout(n_objects: int) -> list[tuple[str, int]]:
    """Names and sizes of the state vector's fields, in order (metres, radians, m/s, rad/s, world frame)."""
    robot = [
        ("ee_position", 3),
        ("ee_yaw_cos_sin", 2),
        ("finger_gap", 1),
        ("ee_linear_velocity", 3),
        ("joint_positions", 7),
        ("joint_velocities", 7),
    ]
    objects = [
        (f"object{i}_{field}", size)
        for i in range(n_objects)
        for field, size in (
            ("position", 3),
            ("quaternion", 4),
            ("linear_velocity", 3),
            ("angular_velocity", 3),
            ("on_table", 1),
        )
    ]
    return robot + objects


class Sensors:
    """Renders what the current step needs, once: cache cleared by ``invalidate`` after every physics change."""

    def __init__(self, cell: Workcell, image_size: tuple[int, int], grid: HeightmapGrid) -> None:
        self.cell = cell
        self.width, self.height = image_size
        self.grid = grid
        self._renderers: dict[tuple[int, int], CameraRenderer] = {}
        self._cache: dict[tuple[str, ...], Any] = {}
        # Segmentation: geom id -> label (0 background, 1 robot, 2 + i object slot i); index 0 is "no geom".
        model = cell.model
        labels = np.zeros(model.ngeom + 1, dtype=np.uint8)
        robot_bodies = np.array(sorted(cell.robot.body_ids))
        labels[1:][np.isin(model.geom_bodyid, robot_bodies)] = 1
        for slot, body in enumerate(cell.object_ids):
            labels[1:][model.geom_bodyid == body] = 2 + slot
        self._labels = labels

    def invalidate(self) -> None:
        self._cache.clear()

    def _renderer(self, width: int, height: int) -> CameraRenderer:
        if (width, height) not in self._renderers:
            self._renderers[(width, height)] = CameraRenderer(self.cell.model, width, height, "fast")
        return self._renderers[(width, height)]

    def rgbd(self, camera: str, width: int | None = None, height: int | None = None) -> tuple[np.ndarray, np.ndarray]:
        width, height = width or self.width, height or self.height
        key = ("rgbd", camera, str(width), str(height))
        if key not in self._cache:
            self._cache[key] = self._renderer(width, height).render_rgbd(self.cell.data, camera)
        return self._cache[key]

    def segmentation(self, camera: str) -> np.ndarray:
        key = ("segmentation", camera)
        if key not in self._cache:
            ids = self._renderer(self.width, self.height).render(self.cell.data, camera, "segmentation")
            self._cache[key] = self._labels[ids + 1]
        return self._cache[key]

    def camera_model(self, camera: str, width: int | None = None, height: int | None = None) -> CameraModel:
        """The pinhole model of ``camera`` as it is posed now (the wrist camera moves)."""
        return CameraModel.from_mujoco(
            self.cell.model, self.cell.data, camera, width or self.width, height or self.height
        )

    def heightmap(self) -> tuple[np.ndarray, np.ndarray]:
        """(heights (rows, cols) metres, colours (rows, cols, 3) uint8) from the overhead RGB-D."""
        key = ("heightmap",)
        if key not in self._cache:
            camera, width, height = HEIGHTMAP_CAMERA
            rgb, depth = self.rgbd(camera, width, height)
            model = self.camera_model(camera, width, height)
            self._cache[key] = heightmap_from_rgbd(self.grid, model, rgb, depth)
        return self._cache[key]

    def close(self) -> None:
        for renderer in self._renderers.values():
            renderer.close()
        self._renderers.clear()


class ObservationBuilder:
    """Builds the observation space and the observations of one env configuration."""

    def __init__(
        self,
        cell: Workcell,
        modalities: tuple[str, ...],
        cameras: tuple[str, ...],
        sensors: Sensors,
        goal_size: int | None,
        extra_state: int = 0,
        command_size: int = 0,
        goal_heightmap: Callable[[HeightmapGrid], np.ndarray | None] | None = None,
    ) -> None:
        """``goal_heightmap``: draws a goal-conditioned task's goal on a grid (``Task.goal_heightmap``); with a
        heightmap modality, its drawing (if not None) is the ``goal_heightmap`` entry."""
        self.cell, self.modalities, self.cameras, self.sensors = cell, modalities, cameras, sensors
        self._needs_state = bool({"state", "proprio"} & set(modalities))
        self.goal_size = goal_size  # None: not goal-conditioned
        self.n_objects = len(cell.object_ids)
        #: Applied to depth observations (domain randomisation's sensor noise): (depth (H, W) m, far m) -> depth.
        self.depth_filter: Callable[[np.ndarray, float], np.ndarray] | None = None
        self._far = float(cell.model.vis.map.zfar * cell.model.stat.extent)
        #: State entries after the objects: the task's properties, then the goal of a primitive-mode goal task.
        self.extra_size = extra_state
        self.state_size = ROBOT_STATE_SIZE + OBJECT_STATE_SIZE * self.n_objects + extra_state
        self._free_qvel = np.array(
            [cell.model.jnt_dofadr[cell.model.body_jntadr[b]] for b in cell.object_ids], dtype=int
        ).reshape(-1, 1) + np.arange(6)
        self._velocity = np.zeros(6)
        self._buffer = np.zeros(self.state_size)
        robot = cell.robot
        self._arm_qpos, self._arm_qvel = fast_index(robot.arm_qpos_idx), fast_index(robot.arm_qvel_idx)
        self._object_ids = fast_index(np.asarray(cell.object_ids, dtype=int))
        self._objects = self._buffer[ROBOT_STATE_SIZE : ROBOT_STATE_SIZE + OBJECT_STATE_SIZE * self.n_objects].reshape(
            self.n_objects, OBJECT_STATE_SIZE
        )
        self._angular = np.zeros((self.n_objects, 3, 1))
        spaces: dict[str, gym.Space] = {}
        height, width = sensors.height, sensors.width
        for modality in modalities:
            if modality == "state":
                key = "observation" if goal_size is not None else "state"
                spaces[key] = gym.spaces.Box(-STATE_BOUND, STATE_BOUND, (self.state_size,), dtype=np.float32)
            elif modality == "proprio":
                spaces["proprio"] = gym.spaces.Box(-STATE_BOUND, STATE_BOUND, (ROBOT_STATE_SIZE,), dtype=np.float32)
            elif modality == "heightmap":
                rows, cols = sensors.grid.shape
                high = np.full((rows, cols, 4), 1.0, dtype=np.float32)
                high[..., 3] = sensors.grid.bounds[2][1] - sensors.grid.bounds[2][0]
                spaces["heightmap"] = gym.spaces.Box(np.zeros_like(high), high, dtype=np.float32)
                if goal_heightmap is not None and goal_heightmap(sensors.grid) is not None:
                    spaces["goal_heightmap"] = gym.spaces.Box(0.0, high[..., 3:], dtype=np.float32)
                    self._goal_heightmap = goal_heightmap
            else:
                for camera in cameras:
                    spaces[self.image_key(camera, modality)] = self._image_space(modality, height, width)
        if command_size:
            spaces["command"] = gym.spaces.Box(0.0, 1.0, (command_size,), dtype=np.float32)
        if goal_size is not None:
            spaces["achieved_goal"] = gym.spaces.Box(-STATE_BOUND, STATE_BOUND, (goal_size,), dtype=np.float32)
            spaces["desired_goal"] = gym.spaces.Box(-STATE_BOUND, STATE_BOUND, (goal_size,), dtype=np.float32)
        self.keys = list(spaces)
        self.space: gym.Space = spaces[self.keys[0]] if len(spaces) == 1 else gym.spaces.Dict(spaces)

    def image_key(self, camera: str, modality: str) -> str:
        return modality if len(self.cameras) == 1 else f"{camera}_{modality}"

    def _image_space(self, modality: str, height: int, width: int) -> gym.spaces.Box:
        if modality == "rgb":
            return gym.spaces.Box(0, 255, (height, width, 3), dtype=np.uint8)
        if modality == "depth":
            return gym.spaces.Box(0.0, self._far, (height, width, 1), dtype=np.float32)
        return gym.spaces.Box(0, 1 + self.n_objects, (height, width, 1), dtype=np.uint8)  # labels 0 .. 1 + n

    def state(self, extra: np.ndarray | None = None) -> np.ndarray:
        """The state vector (see ``state_layout``), float32."""
        cell, robot, data = self.cell, self.cell.robot, self.cell.data
        buffer, site = self._buffer, robot.site_id
        buffer[0:3] = data.site_xpos[site]
        rotation = data.site_xmat[site]
        x, y = float(rotation[0]), float(rotation[3])  # the closing axis, projected on the table
        norm = max(math.hypot(x, y), 1e-9)
        buffer[3], buffer[4] = x / norm, y / norm
        buffer[5] = robot.finger_gap
        mujoco.mj_objectVelocity(cell.model, data, mujoco.mjtObj.mjOBJ_SITE, site, self._velocity, 0)
        buffer[6:9] = self._velocity[3:]
        buffer[9:16] = data.qpos[self._arm_qpos]
        buffer[16:23] = data.qvel[self._arm_qvel]
        if self.n_objects:
            ids, objects = self._object_ids, self._objects
            objects[:, 0:3] = data.xpos[ids]
            objects[:, 3:7] = data.xquat[ids]
            velocity = data.qvel[self._free_qvel]
            objects[:, 7:10] = velocity[:, :3]  # a free joint's linear velocity is in the world frame,
            self._angular[:, :, 0] = velocity[:, 3:]  # its angular velocity in the body frame
            objects[:, 10:13] = np.matmul(data.xmat[ids].reshape(-1, 3, 3), self._angular)[:, :, 0]
            objects[:, 13] = data.xpos[ids, 2] > -0.1
        if extra is not None:
            buffer[self.state_size - len(extra) :] = extra
        return bounded(buffer)

    def observe(
        self,
        goals: tuple[np.ndarray, np.ndarray] | None,
        extra: np.ndarray | None = None,
        command: np.ndarray | None = None,
    ) -> Any:
        """The observation: ``goals`` (achieved, desired) of a goal-conditioned env, ``extra`` state entries
        (``extra_size``) and the task's ``command``."""
        out: dict[str, Any] = {}
        if "command" in self.keys:
            out["command"] = np.asarray(command, dtype=np.float32)
        # One state vector serves both "state" and "proprio" (its first ROBOT_STATE_SIZE entries).
        state = self.state(extra) if self._needs_state else None
        for modality in self.modalities:
            if modality == "state":
                out["observation" if self.goal_size is not None else "state"] = state
            elif modality == "proprio":
                out["proprio"] = state[:ROBOT_STATE_SIZE].copy()
            elif modality == "heightmap":
                heights, colours = self.sensors.heightmap()
                out["heightmap"] = np.concatenate([colours / np.float32(255.0), heights[..., None]], axis=-1).astype(
                    np.float32
                )
                if "goal_heightmap" in self.keys:
                    out["goal_heightmap"] = self._goal_heightmap(self.sensors.grid)[..., None].astype(np.float32)
            else:
                for camera in self.cameras:
                    key = self.image_key(camera, modality)
                    if modality == "segmentation":
                        out[key] = self.sensors.segmentation(camera)[..., None]
                    else:
                        rgb, depth = self.sensors.rgbd(camera)
                        if modality == "depth" and self.depth_filter is not None:
                            depth = self.depth_filter(depth, self._far)
                        out[key] = rgb if modality == "rgb" else depth[..., None]
        if goals is not None:
            out["achieved_goal"] = bounded(goals[0])
            out["desired_goal"] = bounded(goals[1])
        return out[self.keys[0]] if len(self.keys) == 1 else out
