"""How learned policies are made: what ``train.py`` runs, and what a run leaves behind.

``config``: the checked ``TrainConfig``, the algorithm table and the envs a config describes; ``training``:
runs (SB3 models, validation through ``evaluation``'s episodes, atomic checkpoints, resume); ``seed_runs`` and
``seed_figures``: one config over several training seeds and its figures.  ``heightmap_policy``: the
``pixel`` mode's heightmap Q-network; ``policy_files``: policies as data (safetensors + JSON).
``demonstrations``: any agent's episodes recorded as Minari datasets; ``datasets``: those datasets read as
data; ``imitation`` and ``heightmap_imitation``: learning from them.  ``records``: a run's evaluation log,
learning curve, best policy and model card, and shipping it as a checkpoint.  ``falls``: the fall-dynamics
model (a ConvLSTM predicting how a struck tower falls) and its training runs, which ``train.py`` runs as it
runs a policy's (a ``kind: fall_dynamics`` config), with its shipped models.
"""
