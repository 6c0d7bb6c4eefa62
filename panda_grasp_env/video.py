"""Record a workcell's motion to MP4 from one camera, with a caption drawn on each frame."""

from __future__ import annotations

import os
from pathlib import Path

import cv2
import imageio.v2 as imageio
import numpy as np

from panda_grasp_env.rendering import CameraRenderer
from panda_grasp_env.workcell import Workcell


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
        self.fps = 1.0 / (cell.control_dt * every)
        self.renderer = CameraRenderer(cell.model, width, height, profile=profile)
        self.frames: list[np.ndarray] = []
        self.caption = ""
        self.frames_written = 0
        self._count = 0
        cell.step_hooks.append(self._on_step)

    def _on_step(self, cell: Workcell) -> None:
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
        if self._on_step in self.cell.step_hooks:
            self.cell.step_hooks.remove(self._on_step)
        path = Path(path)
        tmp = path.with_name(path.stem + ".partial" + path.suffix)
        imageio.mimwrite(tmp, self.frames, fps=self.fps, codec="libx264", macro_block_size=8)
        os.replace(tmp, path)
        self.frames_written = len(self.frames)
        self.frames.clear()
        self.renderer.close()
        return path
