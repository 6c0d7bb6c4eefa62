"""Decision makers that choose actions, and how the learned ones are trained.

Agents (``base.Agent``): random, planned (perception-based: ``towers``, ``grasping`` with ``push_planner``,
``put_in_bin``), oracle (the same on true poses), scripted low-level experts (``experts``) and shipped learned
policies (``learned``, ``policy_agent``), registered for ``evaluate.py`` in ``registry``.  Learning: configs and
runs (``config``, ``training``, ``seed_runs``, ``records``, ``policy_files``), the heightmap Q-network
(``heightmap_policy``), demonstrations and imitation (``demonstrations``, ``datasets``, ``imitation``,
``heightmap_imitation``).  Evaluation: the benchmark's protocol, episodes, runner, metrics and report
(the ``evaluation`` package), and training seeds' figures (``seed_figures``).
"""
