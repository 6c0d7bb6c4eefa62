"""Record motion to MP4: a workcell from one camera with a caption (``VideoRecorder``), or an env through
Gymnasium's ``RecordVideo`` with the frames inside primitives (``RecordMotionVideo``)."""

from __future__ import annotations

import os
from pathlib import Path

import cv2
import gymnasium as gym
import imageio.v2 as imageio
import numpy as np

from panda_grasp_env.sim.rendering import CameraRenderer
from panda_grasp_env.sim.workcell import Workcell


class VideoRecorder:
    """Grabs a frame (``pretty`` profile by default) every ``every`` control steps while attached to a workcell.

    The video plays in real time: its frame rate is the control rate / ``every``.
    """

    def __init__(
        self,
        cell: Workcell,
        camera: str = "front",
        width: int = 640,
        height: int = 480,
        every: int = 2,
        profile: str = "pretty",
    ) -> None:
        self.cell = cell
        self.camera = camera
        self.every = every
        self.fps = 1.0 / (cell.physics.control_dt * every)
        self.renderer = CameraRenderer(cell.model, width, height, profile=profile)
        self.frames: list[np.ndarray] = []
        self.caption = ""
        self.frames_written = 0
        self._count = 0
        cell.physics.add_observer(self.on_control_step)

    def on_control_step(self, cell: Workcell) -> None:
        """Count the step; every ``every``-th, grab a frame with the caption and the simulated time."""
        self._count += 1
        if self._count % self.every:
            return
        frame = self.renderer.render(cell.data, self.camera, "rgb").copy()
        if self.caption:
            text = f"{self.caption}   t={cell.sim_time:5.1f}s"
            cv2.putText(frame, text, (12, 28), cv2.FONT_HERSHEY_SIMPLEX, 0.7, (0, 0, 0), 4, cv2.LINE_AA)
            cv2.putText(frame, text, (12, 28), cv2.FONT_HERSHEY_SIMPLEX, 0.7, (255, 255, 255), 1, cv2.LINE_AA)
        self.frames.append(frame)

    def save(self, path: Path) -> Path:
        """Write the frames to ``path`` atomically (temp file + rename) and detach from the workcell."""
        if self.on_control_step in self.cell.physics.observers:
            self.cell.physics.remove_observer(self.on_control_step)
        path = Path(path)
        tmp = path.with_name(path.stem + ".partial" + path.suffix)
        imageio.mimwrite(tmp, self.frames, fps=self.fps, codec="libx264", macro_block_size=8)
        os.replace(tmp, path)
        self.frames_written = len(self.frames)
        self.frames.clear()
        self.renderer.close()
        return path


class RecordMotionVideo(gym.wrappers.RecordVideo):
    """Gymnasium's ``RecordVideo`` that keeps every frame an ``rgb_array_list`` env returns.

    ``RecordVideo`` keeps only the last frame of a list, so a primitive -- seconds of motion in one
    ``step`` -- would be one still.  Made with ``render_mode="rgb_array_list"``, ``PandaEnv`` renders at
    ``metadata["render_fps"]`` of simulated time inside primitives too, and this wrapper writes them all: the
    video plays in real time.  Arguments are ``RecordVideo``'s.
    """

    def _capture_frame(self) -> None:
        frames = self.env.render()
        if not isinstance(frames, list):
            raise ValueError(f"RecordMotionVideo needs render_mode='rgb_array_list', not {self.env.render_mode!r}")
        self.render_history += frames
        self.recorded_frames += frames
