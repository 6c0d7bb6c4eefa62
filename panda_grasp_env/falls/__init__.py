"""Fall dynamics in one place: predicting how a pushed or struck tower falls, from overhead RGB-D.

* ``recorder`` -- records falling-tower sequences from the env (``python -m panda_grasp_env.falls``);
* ``dataset`` -- the shard format the recorder writes, and a checked loader with train/val/test splits;
* ``model`` -- the ConvLSTM that predicts the next segmentation frames, its inputs and checkpoint loader;
* ``baselines`` -- the mask-shifting predictors it is compared with;
* ``metrics`` and ``directions`` -- how well a predictor segments the frames, and which way it says a
  tower falls;
* ``config`` -- the checked configs: the recorder's settings and a training run's (``train.py`` with a
  ``kind: fall_dynamics`` config);
* ``training`` -- training runs of the model, its final test against the baselines and re-scoring on any
  recorded dataset (``train.py --retest``);
* ``records`` -- what a run leaves (strips, curve, card) and the shipped models in ``checkpoints/``.
"""
