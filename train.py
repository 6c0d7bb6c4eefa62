"""Train a policy or a fall-dynamics model from a config: ``python train.py --config configs/<name>.yaml``.

The program is ``panda_grasp_env.commands.train`` (also installed as ``panda-train``); ``--help`` lists it all.
"""

import sys

from panda_grasp_env.commands.train import main

if __name__ == "__main__":
    sys.exit(main())
