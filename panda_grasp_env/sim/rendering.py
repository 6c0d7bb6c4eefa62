"""Headless RGB, depth and segmentation rendering from the workcell's cameras.

Two profiles:

* ``fast`` (observations): no multisampling, no shadows or reflections, and the
  robot drawn with its collision geoms (2.3 k triangles) instead of its visual
  meshes (134 k) -- about 8-16x the frame rate of the authored settings on a
  software-GL machine (84x84 RGB: 14-18 fps as authored, ~130 without multisampling, shadows and
  reflections, ~290 with collision geoms too; ``benchmarks/throughput.py`` prints today's rates);
* ``pretty`` (videos): 4x multisampling, shadows, reflections, visual meshes.

The GL backend is ``MUJOCO_GL``, which importing ``panda_grasp_env`` sets to ``egl`` on Linux (its
``__init__``) unless the user chose one.
Depth is metres along the camera's optical axis; segmentation is per-pixel
geom id (-1 for background).  ``EnvRenderer`` is what an env's ``render_mode``
shows: front-camera frames, their video, or MuJoCo's viewer.
"""

from __future__ import annotations

import atexit
import os
import socket
import sys
from collections.abc import Callable
from typing import Any

import mujoco
import numpy as np

from panda_grasp_env.geometry import is_count
from panda_grasp_env.sim.workcell import Workcell

PROFILES = ("fast", "pretty")
MODALITIES = ("rgb", "depth", "segmentation")
_GEOM_GROUPS = {"fast": (0, 2), "pretty": (0, 1)}
#: Every render mode the env knows.
RENDER_MODES = ("rgb_array", "rgb_array_list", "depth_array", "human")


#: How long (seconds) a display's server may take to accept a connection before it counts as not answering.
DISPLAY_TIMEOUT = 1.0


def _answers(address: str | tuple[str, int], family: int) -> bool:
    """Whether a server accepts a connection at ``address`` within ``DISPLAY_TIMEOUT``."""
    try:
        with socket.socket(family, socket.SOCK_STREAM) as probe:
            probe.settimeout(DISPLAY_TIMEOUT)
            probe.connect(address)
        return True
    except OSError:
        return False


def x_display_answers(display: str) -> bool:
    """Whether the X server of ``display`` (``DISPLAY``: ``[host]:number[.screen]``) accepts a connection: its
    local socket (``/tmp/.X11-unix/X<number>``, or the abstract one Linux servers also listen on), else TCP
    port 6000 + number on the host."""
    host, _, rest = display.rpartition(":")
    number = rest.split(".")[0]
    if not number.isdigit():
        return False
    if host in ("", "unix") or host.startswith("/"):
        path = host if host.startswith("/") else f"/tmp/.X11-unix/X{number}"
        return _answers(path, socket.AF_UNIX) or (
            sys.platform.startswith("linux") and _answers(f"\0/tmp/.X11-unix/X{number}", socket.AF_UNIX)
        )
    return _answers((host, 6000 + int(number)), socket.AF_INET)


def display_available() -> bool:
    """Whether an on-screen window can open: on Linux an X11 or Wayland display must be named and its server
    must answer (without one, MuJoCo's viewer ends the process from C, past any Python handler); other systems
    always have one."""
    if not sys.platform.startswith("linux"):
        return True
    wayland, runtime = os.environ.get("WAYLAND_DISPLAY"), os.environ.get("XDG_RUNTIME_DIR", "")
    if wayland and _answers(wayland if wayland.startswith("/") else os.path.join(runtime, wayland), socket.AF_UNIX):
        return True
    display = os.environ.get("DISPLAY")
    return bool(display) and x_display_answers(display)


def advertised_render_modes() -> list[str]:
    """``RENDER_MODES`` less "human" (a window) where none can open: checkers that build every advertised
    mode (Gymnasium's ``check_env``) then work on servers."""
    return [mode for mode in RENDER_MODES if mode != "human" or display_available()]


#: The MuJoCo renderers of the open ``CameraRenderer``s.  Holding them here keeps the garbage collector from
#: ever finalising one: a collection can start at any allocation, also between another renderer's
#: ``make_current`` and its draw, and freeing a GL context there leaves that draw in the wrong context or in
#: none (garbled frames).  A ``CameraRenderer`` dropped without ``close()`` only queues its renderer in
#: ``_DROPPED``; the next one to be made, to draw or to close frees the queue first.
_OPEN: set[mujoco.Renderer] = set()
_DROPPED: list[mujoco.Renderer] = []
#: The exit hook ``_track`` registered (empty until the first renderer is made).
_EXIT_HOOK: list[Callable[[], None]] = []


def _free(renderer: mujoco.Renderer) -> None:
    """Free ``renderer``'s GL resources (idempotent).  MuJoCo 3.x's ``Renderer.close`` frees the render
    context's framebuffers and textures in whichever GL context is current, which is another renderer's if
    that one drew last: its next frames come back empty (NaN depth).  So the context is freed here with its
    own GL context current first; 4.x does the same itself."""
    if renderer._mjr_context is not None:
        if renderer._gl_context:
            renderer._gl_context.make_current()
        renderer._mjr_context.free()
        renderer._mjr_context = None
    renderer.close()
    _OPEN.discard(renderer)


def _free_open_renderers() -> None:
    """Free every renderer still open (at exit, before the GL platform closes its display: see ``_track``)."""
    _free_dropped()
    for renderer in list(_OPEN):
        _free(renderer)


def _track(renderer: mujoco.Renderer) -> None:
    """Count ``renderer`` open; after the process's first, free every open one at exit.  The exit hook is
    registered after the GL platform's own (MuJoCo's EGL module closes its display at exit, registering that
    when it makes its first context), so it runs first: an env still open at exit -- a kept benchmark env, a
    script's -- no longer fails to make its contexts current on a closed display."""
    if not _EXIT_HOOK:
        atexit.register(_free_open_renderers)
        _EXIT_HOOK.append(_free_open_renderers)
    _OPEN.add(renderer)


def _free_dropped() -> None:
    """Free the renderers of ``CameraRenderer``s dropped without ``close()``, outside any draw."""
    while _DROPPED:
        _free(_DROPPED.pop())


class CameraRenderer:
    """Renders one image size in one profile; reuse it every step (creating GL contexts is slow)."""

    def __init__(self, model: mujoco.MjModel, width: int, height: int, profile: str = "fast") -> None:
        if profile not in PROFILES:
            raise ValueError(f"unknown render profile {profile!r}; valid: {list(PROFILES)}")
        for name, value in (("width", width), ("height", height)):
            if not is_count(value) or value < 1:
                raise ValueError(f"{name} must be a positive int, got {value!r}")
        if width > model.vis.global_.offwidth or height > model.vis.global_.offheight:
            model.vis.global_.offwidth = max(width, model.vis.global_.offwidth)
            model.vis.global_.offheight = max(height, model.vis.global_.offheight)
        self.model = model
        self.profile = profile
        # Multisampling and the tessellation of built-in shapes are fixed when the GL context is made.
        # The fast profile draws capsules and cylinders with 16 x 8 facets instead of 28 x 16: the
        # robot's 24 capsules were 80 % of an 84 x 84 frame's cost (2.6 -> 1.1 ms), for a radial error
        # of at most 2 % of the radius.
        quality = model.vis.quality
        authored = (quality.offsamples, quality.numslices, quality.numstacks)
        if profile == "fast":
            quality.offsamples, quality.numslices, quality.numstacks = 0, 16, 8
        else:
            quality.offsamples = max(4, authored[0])
        _free_dropped()
        try:
            self._renderer = mujoco.Renderer(model, height=height, width=width)
        finally:
            quality.offsamples, quality.numslices, quality.numstacks = authored
        _track(self._renderer)
        self.width, self.height = width, height
        # Scene flags persist across update_scene calls: set them once.
        fancy = profile == "pretty"
        self._renderer.scene.flags[mujoco.mjtRndFlag.mjRND_SHADOW] = fancy
        self._renderer.scene.flags[mujoco.mjtRndFlag.mjRND_REFLECTION] = fancy
        self.option = mujoco.MjvOption()
        self.option.geomgroup[:] = 0
        for group in _GEOM_GROUPS[profile]:
            self.option.geomgroup[group] = 1
        self._mode = "rgb"

    def _set_mode(self, modality: str) -> None:
        if modality not in MODALITIES:
            raise ValueError(f"unknown modality {modality!r}; valid: {list(MODALITIES)}")
        if modality == self._mode:
            return
        self._renderer.disable_depth_rendering()
        self._renderer.disable_segmentation_rendering()
        if modality == "depth":
            self._renderer.enable_depth_rendering()
        elif modality == "segmentation":
            self._renderer.enable_segmentation_rendering()
        self._mode = modality

    def render(self, data: mujoco.MjData, camera: str | int, modality: str = "rgb") -> np.ndarray:
        """One frame: ``rgb`` (H, W, 3) uint8, ``depth`` (H, W) float32 metres, ``segmentation`` (H, W) int32 geom ids."""
        _free_dropped()
        self._set_mode(modality)
        self._renderer.update_scene(data, camera=camera, scene_option=self.option)
        image = self._renderer.render()
        if modality == "depth":
            return image.astype(np.float32, copy=False)
        if modality == "segmentation":
            ids = image[..., 0].astype(np.int32)
            ids[image[..., 1] != int(mujoco.mjtObj.mjOBJ_GEOM)] = -1
            return ids
        return image

    def render_rgbd(self, data: mujoco.MjData, camera: str | int) -> tuple[np.ndarray, np.ndarray]:
        """RGB (H, W, 3) uint8 and depth (H, W) float32 metres from a single render pass.

        ``mujoco.Renderer`` renders the scene once per modality; reading both
        buffers after one ``mjr_render`` halves the cost of RGB-D observations.
        (Uses the renderer's GL context, which has these names in MuJoCo 3.x and 4.x.)
        """
        _free_dropped()
        self._set_mode("rgb")
        renderer = self._renderer
        renderer.update_scene(data, camera=camera, scene_option=self.option)
        rgb = np.empty((self.height, self.width, 3), dtype=np.uint8)
        depth = np.empty((self.height, self.width), dtype=np.float32)
        # Current right before drawing: nothing allocated in between can run a finaliser that releases it.
        if renderer._gl_context:
            renderer._gl_context.make_current()
        mujoco.mjr_render(renderer._rect, renderer.scene, renderer._mjr_context)
        mujoco.mjr_readPixels(rgb, depth, renderer._rect, renderer._mjr_context)
        # Reversed-z depth buffer (1 at the near plane, 0 at the far one) -> metres along the optical axis.
        extent = self.model.stat.extent
        near, far = self.model.vis.map.znear * extent, self.model.vis.map.zfar * extent
        depth = (near / (depth.astype(np.float64) * (1.0 - near / far) + near / far)).astype(np.float32)
        # OpenGL rows run bottom-up; contiguous copies, since torch rejects negative strides.
        return np.ascontiguousarray(rgb[::-1]), np.ascontiguousarray(depth[::-1])

    def close(self) -> None:
        """Free the GL resources (idempotent)."""
        _free_dropped()
        _free(self._renderer)

    def __del__(self) -> None:
        # Dropped without close(): a finaliser may run inside another renderer's draw, so it touches no GL.
        renderer = getattr(self, "_renderer", None)
        if _OPEN is None or _DROPPED is None:  # interpreter shutdown: the module's globals are gone already
            return
        if renderer in _OPEN and renderer not in _DROPPED:
            _DROPPED.append(renderer)

    def __enter__(self) -> CameraRenderer:
        return self

    def __exit__(self, *exc_info: object) -> None:
        self.close()


class RenderCache:
    """One renderer per (width, height, profile), created on first use."""

    def __init__(self, model: mujoco.MjModel) -> None:
        self.model = model
        self._renderers: dict[tuple[int, int, str], CameraRenderer] = {}

    def render(
        self,
        data: mujoco.MjData,
        camera: str,
        width: int,
        height: int,
        modality: str = "rgb",
        profile: str = "fast",
    ) -> np.ndarray:
        key = (width, height, profile)
        if key not in self._renderers:
            self._renderers[key] = CameraRenderer(self.model, width, height, profile)
        return self._renderers[key].render(data, camera, modality)

    def close(self) -> None:
        for renderer in self._renderers.values():
            renderer.close()
        self._renderers.clear()


class EnvRenderer:
    """What an env's ``render_mode`` shows of ``cell``, from the front camera at ``size`` (width, height) pixels:
    ``rgb_array`` a (height, width, 3) uint8 frame (``pretty`` profile); ``depth_array`` the (height, width)
    float32 metres of ``depth()``; ``rgb_array_list`` the frames since the episode began or the last
    ``render``, one each time simulated time passes a multiple of ``1 / fps`` seconds (``on_control_step``, a
    step observer the env adds: inside primitives too); ``human`` MuJoCo's passive viewer.  None: nothing (no
    renderer)."""

    def __init__(
        self, cell: Workcell, mode: str | None, size: tuple[int, int], fps: float, depth: Callable[[], np.ndarray]
    ) -> None:
        self.cell, self.mode, self.size, self.fps, self._depth = cell, mode, size, fps, depth
        self._renderer: CameraRenderer | None = None
        self._viewer: Any = None
        self._frames: list[np.ndarray] = []
        self._next_frame_time = np.inf  # set at each episode's start

    def pause(self) -> None:
        """Take no frames until ``start_episode`` (none of a scene being laid out and settled)."""
        self._next_frame_time = np.inf

    def start_episode(self) -> None:
        """After a reset: show it (``human``), or begin the frame list with it (``rgb_array_list``)."""
        self.show()
        if self.mode == "rgb_array_list":
            self._frames = [self._rgb_frame()]
            self._next_frame_time = self.cell.sim_time + 1.0 / self.fps

    def show(self) -> None:
        """Bring the viewer up to date (``human`` only: the other modes render when asked)."""
        if self.mode == "human":
            self.render()

    def render(self) -> np.ndarray | list[np.ndarray] | None:
        """The frame (or, ``rgb_array_list``, the frames) of the mode; None for ``human`` and None."""
        if self.mode == "human":
            if self._viewer is None:
                import mujoco.viewer

                self._viewer = mujoco.viewer.launch_passive(self.cell.model, self.cell.data)
            self._viewer.sync()
            return None
        if self.mode == "depth_array":
            return self._depth()
        if self.mode == "rgb_array_list":
            frames, self._frames = self._frames, []
            return frames
        return None if self.mode is None else self._rgb_frame()

    def _rgb_frame(self) -> np.ndarray:
        if self._renderer is None:
            self._renderer = CameraRenderer(self.cell.model, *self.size, "pretty")
        return self._renderer.render(self.cell.data, "front", "rgb")

    def on_control_step(self, cell: Workcell) -> None:
        """``rgb_array_list``: take a frame if simulated time has passed the next multiple of ``1 / fps``."""
        if cell.sim_time + 1e-9 < self._next_frame_time:
            return
        self._frames.append(self._rgb_frame())
        while self._next_frame_time <= cell.sim_time + 1e-9:
            self._next_frame_time += 1.0 / self.fps

    def close(self) -> None:
        """Free the renderer and close the viewer (idempotent)."""
        if self._renderer is not None:
            self._renderer.close()
            self._renderer = None
        if self._viewer is not None:
            self._viewer.close()
            self._viewer = None
