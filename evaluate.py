"""The main job: benchmark agents on every task through the same ``env.step`` loop: ``python evaluate.py``.

The program is ``panda_grasp_env.commands.evaluate`` (also installed as ``panda-evaluate``); ``--help`` lists it all.
"""

import os
import sys

os.environ.setdefault("MUJOCO_GL", "egl")  # offscreen rendering even where a display exists

from panda_grasp_env.commands.evaluate import main  # noqa: E402

if __name__ == "__main__":
    sys.exit(main())
