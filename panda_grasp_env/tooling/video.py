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
    """Grabs a frame (``pretty`` profile by default) every ``every`` control steps while attached to a workcell,
    and hands it to the MP4 encoder at once: a recording holds one frame in memory, however long it runs.

    The video plays in real time: its frame rate is the control rate / ``every``.  It is written to
    ``<path stem>.partial.mp4`` as it goes and renamed to ``path`` by ``save`` (a recording cut short leaves
    no file at ``path``).
    """

    def __init__(
        self,
        cell: Workcell,
        path: Path | str,
        camera: str = "front",
        width: int = 640,
        height: int = 480,
        every: int = 2,
        profile: str = "pretty",
        active: bool = True,
    ) -> None:
        """``active``: grab frames from the first control step; False waits until ``active`` is set (a benchmark
        clip starts at its episode's first state, not in the reset that lays the scene out)."""
        self.cell = cell
        self.active = active
        self.path = Path(path)
        self.camera = camera
        self.every = every
        self.fps = 1.0 / (cell.physics.control_dt * every)
        self.renderer = CameraRenderer(cell.model, width, height, profile=profile)
        self._partial = self.path.with_name(self.path.stem + ".partial" + self.path.suffix)
        self._writer = imageio.get_writer(self._partial, fps=self.fps, codec="libx264", macro_block_size=8)
        #: The first line of every frame (what is filmed: an agent, a task, a seed), then ``status`` (what
        #: happens now: the last primitive's outcome), then the simulated time; empty lines are left out.
        self.caption = ""
        self.status = ""
        self.frames_written = 0
        self._count = 0
        cell.physics.add_observer(self.on_control_step)

    def on_control_step(self, cell: Workcell) -> None:
        """Count the step; every ``every``-th, grab a frame with the caption and the simulated time."""
        if not self.active:
            return
        self._count += 1
        if self._count % self.every:
            return
        frame = self.renderer.render(cell.data, self.camera, "rgb").copy()
        lines = [line for line in (self.caption, self.status) if line]
        if lines:
            write_lines(frame, [*lines, f"t = {cell.sim_time:5.1f} s"])
        self._writer.append_data(frame)
        self.frames_written += 1

    def save(self) -> Path:
        """Finish the video, put it at ``path`` (rename of the partial file) and detach from the workcell."""
        if self.on_control_step in self.cell.physics.observers:
            self.cell.physics.remove_observer(self.on_control_step)
        self._writer.close()
        os.replace(self._partial, self.path)
        self.renderer.close()
        return self.path


def write_lines(frame: np.ndarray, lines: list[str], margin: int = 10) -> None:
    """Draw ``lines`` top left on ``frame`` (H, W, 3), one under another, white on a darkened band; a line
    wider than the frame is drawn smaller, never over its neighbours or past the edge.  (No outline drawn
    as a thicker pass of the same text: OpenCV 5 spaces thicker Hershey text wider, so the two passes drifted
    apart and read as captions printed over each other.)"""
    font, base_scale = cv2.FONT_HERSHEY_SIMPLEX, frame.shape[1] / 900  # 0.53 at 480 pixels wide, 0.71 at 640
    placed, y = [], margin
    for line in lines:
        width, height = cv2.getTextSize(line, font, base_scale, 1)[0]
        scale = base_scale * min(1.0, (frame.shape[1] - 2 * margin) / width)
        y += int(height * scale / base_scale) + 6
        placed.append((line, scale, y, int(width * scale / base_scale)))
    band_width = min(frame.shape[1], max(w for *_, w in placed) + 2 * margin)
    band = frame[: y + margin, :band_width]
    band[:] = band // 3
    for line, scale, baseline, _ in placed:
        cv2.putText(frame, line, (margin, baseline), font, scale, (255, 255, 255), 1, cv2.LINE_AA)


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
