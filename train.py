"""Train a policy or a fall-dynamics model from a config: ``python train.py --config configs/<name>.yaml``.

The program is ``panda_grasp_env.commands.train`` (also installed as ``panda-train``); ``--help`` lists it all.
"""

import os
import signal
import sys


def interrupted_while_loading(signum: int, frame: object) -> None:
    """Ctrl-C while the libraries load (seconds, before anything is read or written): one line, and out.  Raised
    as a ``KeyboardInterrupt`` it would print a traceback, or, landing in a garbage-collection callback, be
    printed as ignored while the run went on."""
    os.write(2, b"\ninterrupted while loading: nothing was read or written; the same command starts again\n")
    os._exit(130)


if __name__ == "__main__":
    signal.signal(signal.SIGINT, interrupted_while_loading)  # main() sets its own once loaded
    from panda_grasp_env.commands.train import main

    sys.exit(main())
