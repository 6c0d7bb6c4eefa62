"""panda_grasp_env: a MuJoCo Franka Panda workcell for tower building, tower breaking and grasping.

Importing the package imports every task module, which registers the task's Gymnasium ids
(see ``registration.py``).
"""

import os
import sys

# The one place the GL backend is chosen (MuJoCo reads MUJOCO_GL when it is first imported): on Linux, frames
# render offscreen through EGL, display or not; observations and videos need no window, and the viewer of
# render_mode="human" opens its own through GLFW.  A MUJOCO_GL the user set wins.
if sys.platform.startswith("linux"):
    os.environ.setdefault("MUJOCO_GL", "egl")

import panda_grasp_env.tasks  # noqa: E402, F401  (registers the tasks and their ids)
from panda_grasp_env.registration import ENV_IDS, TASKS  # noqa: E402
from panda_grasp_env.sim.motion import WORKSPACE  # noqa: E402
from panda_grasp_env.sim.workcell import SPAWN_REGION  # noqa: E402

__version__ = "0.1.0"
#: ``WORKSPACE``: the x, y, z bounds (3, 2) a primitive's target may take, world metres (the table top is z = 0);
#: ``SPAWN_REGION``: the x, y bounds (2, 2) inside it where resets lay objects out.
__all__ = ["ENV_IDS", "SPAWN_REGION", "TASKS", "WORKSPACE"]
