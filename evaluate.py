"""The main job: benchmark agents on every task through the same ``env.step`` loop: ``python evaluate.py``.

The program is ``panda_grasp_env.commands.evaluate`` (also installed as ``panda-evaluate``); ``--help`` lists it all.
"""

import sys

from panda_grasp_env.commands.evaluate import main

if __name__ == "__main__":
    sys.exit(main())
