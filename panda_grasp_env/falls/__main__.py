"""``python -m panda_grasp_env.falls --out data/falls --sequences 2000``: record a falling-tower dataset."""

import os
import sys

os.environ.setdefault("MUJOCO_GL", "egl")

from panda_grasp_env.falls.recorder import main  # noqa: E402

sys.exit(main())
