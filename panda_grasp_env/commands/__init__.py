"""The command-line programs, the layer above the agents: ``train`` (``python train.py`` or ``panda-train``)
and ``evaluate`` (``python evaluate.py`` or ``panda-evaluate``).  The scripts at the repository's root and the
installed console scripts run the same ``main``."""
