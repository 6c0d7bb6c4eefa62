"""panda_grasp_env: a MuJoCo Franka Panda workcell for tower building, tower breaking and grasping.

Importing the package registers its Gymnasium ids (see ``registration.py``).
"""

import os

# Headless machines have no X display: render offscreen through EGL unless told otherwise.
# (Must happen before mujoco is first imported.)
if "DISPLAY" not in os.environ:
    os.environ.setdefault("MUJOCO_GL", "egl")

from panda_grasp_env.registration import ENV_IDS, register_envs  # noqa: E402

register_envs()

__version__ = "0.1.0"
__all__ = ["ENV_IDS", "register_envs"]
