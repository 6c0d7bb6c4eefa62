"""Fall dynamics: predicting how a pushed or struck tower falls, from overhead RGB-D, learned from the sequences
``python -m panda_grasp_env.falls`` records.  Trained by ``train.py`` as policies are (a ``kind: fall_dynamics``
config: the same run folder, resume, card, ship and retest).

* ``config`` -- the checked config of a training run, and what ``--resume`` may change;
* ``dataset`` -- the checked loader of a recorded dataset, with its train/val/test splits;
* ``model`` -- the ConvLSTM that predicts the next segmentation frames, its inputs and checkpoint loader;
  ``tracks`` -- the blocks' tracks and the track head that plans their displacements;
* ``baselines`` -- the mask-shifting predictors it is compared with;
* ``metrics`` and ``directions`` -- how well a predictor segments the frames, and which way it says a
  tower falls;
* ``training`` -- training runs of the model, its final test against the baselines and re-scoring on any
  recorded dataset (``train.py --retest``);
* ``records`` -- what a run leaves (strips, curve, card) and shipping it to ``checkpoints/`` (package data).
"""
