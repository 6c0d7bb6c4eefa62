"""panda_grasp_env: a MuJoCo Franka Panda workcell for tower building, tower breaking and grasping."""

import os

# Headless machines have no X display: render offscreen through EGL unless told otherwise.
# (Must happen before mujoco is first imported.)
if "DISPLAY" not in os.environ:
    os.environ.setdefault("MUJOCO_GL", "egl")

__version__ = "0.1.0"
