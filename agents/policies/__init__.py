"""The agents: everything that chooses actions through the ``Agent`` protocol (``base``) in the ``env.step`` loop.

``random_agent``: the random baseline.  Planned baselines on perception, and their oracle variants on the
simulator's true poses: ``towers`` (build and break), ``grasping`` with its ``push_planner`` (grasping in
clutter and packed scenes), ``put_in_bin``, ``structures`` (with ``structure_views``: building structures,
greedy or with a lookahead in a copy of the simulation; ``structure_builder``: the suite's certificates).
``experts``: scripted low-level experts acting at 25 Hz.
``policy_agent``: any SB3 model or policy as an agent; ``learned``: the shipped learned policies
(``agents/checkpoints/``) loaded by name; ``phased``: agents made of one shipped policy per phase of a task.
``registry``: the ``@register_baseline`` and ``@register_expert`` decorators, and the agents they registered
(``BASELINES``, ``EXPERTS``) for ``evaluate.py``.
"""
