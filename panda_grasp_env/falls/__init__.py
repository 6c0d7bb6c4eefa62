"""Fall dynamics in one place: predicting how a pushed or struck tower falls, from overhead RGB-D.

* ``recorder`` -- records falling-tower sequences from the env (``python -m panda_grasp_env.falls``);
* ``dataset`` -- the shard format the recorder writes, and a checked loader with train/val/test splits;
* ``model`` -- the ConvLSTM that predicts the next segmentation frames, its baselines and metrics;
* ``training`` -- training runs of the model (``train.py`` with a ``kind: fall_dynamics`` config), its
  final test against the baselines, re-scoring on any recorded dataset (``train.py --retest``) and the
  shipped models in ``checkpoints/``.
"""
