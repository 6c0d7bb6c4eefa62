"""Decision makers that choose actions, and how the learned ones are trained.

Agents (``base.Agent``): random, planned (perception-based: ``towers``, ``grasping``, ``put_in_bin``), oracle
(the same on true poses), scripted low-level experts (``experts``) and shipped learned policies (``learned``,
``policy_agent``), registered for ``evaluate.py`` in ``registry``.  Learning: configs and runs (``config``,
``training``, ``seed_runs``, ``records``, ``policy_files``), the heightmap Q-network (``heightmap_policy``),
demonstrations and imitation (``demonstrations``, ``datasets``, ``imitation``).  Evaluation: the benchmark
runner and its figures (``evaluation``, ``seed_figures``).
"""
