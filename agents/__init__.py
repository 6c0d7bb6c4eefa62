"""Decision makers: the agents that act, the benchmark that evaluates them, and how the learned ones are made.

Three sub-packages, bottom first (``tests/test_layout.py`` keeps their imports to this order):

``policies``: the agents -- the ``Agent`` protocol, the random, planned and oracle baselines, scripted low-level
experts, shipped learned policies and the phased agents made of them, and the registry ``evaluate.py`` finds
them in.  ``evaluation``: the benchmark ``evaluate.py`` runs -- its protocol, episodes, runner, metrics and
report.  ``learning``: what ``train.py`` runs -- training configs and runs (validated through ``evaluation``'s
episodes), the heightmap Q-network, policies as files, demonstrations and imitation, run records and shipping,
figures over training seeds, and the fall-dynamics model with its training runs (``learning.falls``).  The one
import against the order: a learned agent (``policies.learned``) reads what learning wrote, its training config
and its policy files.  ``checkpoints/`` holds the shipped learned policies' files (package data; the shipped
fall-dynamics models are ``learning/falls/checkpoints/``).
"""
