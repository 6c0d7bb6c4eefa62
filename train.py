"""Train a policy or a fall-dynamics model from a config: ``python train.py --config configs/<name>.yaml``.

The program is ``panda_grasp_env.commands.train`` (also installed as ``panda-train``); ``--help`` lists it all.
"""

import os
import sys

os.environ.setdefault("MUJOCO_GL", "egl")  # offscreen rendering even where a display exists

from panda_grasp_env.commands.train import main  # noqa: E402

if __name__ == "__main__":
    sys.exit(main())
