"""The command-line programs, the layer above the agents: ``train`` (``python train.py`` or ``panda-train``)
and ``evaluate`` (``python evaluate.py`` or ``panda-evaluate``), with what ``evaluate`` shows people:
``results_page`` (report.html, success.png, failures.png) and ``compare`` (``evaluate.py compare RUN_A
RUN_B``).  The scripts at the repository's root and the installed console scripts run the same ``main``."""
