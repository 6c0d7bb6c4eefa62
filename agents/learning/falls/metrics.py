"""How well a fall-dynamics predictor segments the frames it predicts.

``evaluate``, over every evaluated (sequence, t) of a split, for the prediction of frame t + h from frames
t - context + 1 ... t:

* pixel accuracy: predicted class == true class, over all pixels;
* foreground accuracy: the same over pixels whose *true* class is a block;
* IoU of class c: sum of |pred = c and true = c| / sum of |pred = c or true = c|
  over all evaluated frames (dataset-level); mean block IoU: mean over the block classes.

``test_scores``: these and the fall directions (``directions``) of a model and the baselines on a test split,
and with a settle head its stands/falls answers (``settling``).
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any

import numpy as np

from panda_grasp_env.agents.learning.falls.baselines import BASELINES
from panda_grasp_env.agents.learning.falls.dataset import FallSequences
from panda_grasp_env.agents.learning.falls.directions import fall_directions
from panda_grasp_env.agents.learning.falls.model import FallPredictor, check_compatible, predict_batch
from panda_grasp_env.agents.learning.falls.settling import settle_scores


@dataclass
class Confusion:
    """Accumulated (true, predicted) class counts."""

    n_classes: int

    def __post_init__(self) -> None:
        self.matrix = np.zeros((self.n_classes, self.n_classes), dtype=np.int64)
        self.frames = 0

    def add(self, truth: np.ndarray, predicted: np.ndarray) -> None:
        index = truth.astype(np.int64).ravel() * self.n_classes + predicted.astype(np.int64).ravel()
        self.matrix += np.bincount(index, minlength=self.n_classes**2).reshape(self.n_classes, self.n_classes)
        self.frames += truth.shape[0] if truth.ndim == 3 else 1

    def summary(self, classes: list[str]) -> dict[str, Any]:
        m = self.matrix
        correct = np.diag(m)
        union = m.sum(0) + m.sum(1) - correct
        iou = np.where(union > 0, correct / np.maximum(union, 1), np.nan)
        foreground = m[1:].sum()
        return {
            "frames": int(self.frames),
            "pixel_accuracy": round(float(correct.sum() / m.sum()), 4),
            "foreground_accuracy": round(float(correct[1:].sum() / foreground), 4) if foreground else None,
            "iou": {name: round(float(v), 4) for name, v in zip(classes, iou)},
            "mean_block_iou": round(float(np.nanmean(iou[1:])), 4),
        }


def evaluate(
    model: FallPredictor | None,
    labels: np.ndarray,
    classes: list[str],
    context: int,
    horizons: tuple[int, ...] = (1, 5),
    batch_size: int = 64,
    depth: np.ndarray | None = None,
    baselines: bool = True,
) -> dict[str, dict[str, Any]]:
    """Metrics of the model (if given) and, with ``baselines``, the baselines at each horizon over sequences
    ``labels`` (N, T, S, S) (with their depth images (N, T, S, S) for a ``use_depth`` model).

    Evaluated at every t with ``context`` frames up to t and t + max(horizons) inside the sequence.
    """
    n, length = labels.shape[:2]
    last = length - 1 - max(horizons)
    if last < context - 1:
        raise ValueError(
            f"sequences of {length} frames are too short for context {context} and horizon {max(horizons)}"
        )
    starts = [(i, t) for i in range(n) for t in range(max(context - 1, 1), last + 1)]
    n_classes = len(classes)
    compared = BASELINES if baselines else {}
    scores = {name: {h: Confusion(n_classes) for h in horizons} for name in (["model"] if model else []) + [*compared]}
    for name, baseline in compared.items():
        for i, t in starts:
            for h in horizons:
                scores[name][h].add(labels[i, t + h], baseline(labels[i], t, h))
    if model is not None:
        check_compatible(model, labels, classes, depth)
        model.eval()
        for b in range(0, len(starts), batch_size):
            chunk = starts[b : b + batch_size]
            windows = np.stack([labels[i, t - context + 1 : t + 1] for i, t in chunk])
            depths = np.stack([depth[i, t - context + 1 : t + 1] for i, t in chunk]) if model.use_depth else None
            predicted = predict_batch(model, windows, max(horizons), depths)
            truth_frames = {h: np.stack([labels[i, t + h] for i, t in chunk]) for h in horizons}
            for h in horizons:
                scores["model"][h].add(truth_frames[h], predicted[:, h - 1])
    return {name: {f"t+{h}": c.summary(classes) for h, c in by_h.items()} for name, by_h in scores.items()}


def test_scores(model: FallPredictor, test: FallSequences, context: int) -> dict[str, Any]:
    """The test figures of ``model`` and the baselines on a split: ``metrics`` (``evaluate``), ``direction``
    (``fall_directions``) and, for a model with a settle head, ``settle`` (``settle_scores``)."""
    settle = {"settle": settle_scores(model, test)} if model.settle_frames else {}
    return {
        **settle,
        "metrics": evaluate(model, test.labels, test.classes, context, depth=test.depth),
        "direction": fall_directions(
            model,
            test.labels,
            test.poses,
            test.n_blocks,
            test.crop_origin,
            test.camera,
            test.classes,
            context,
            test.depth,
        ),
    }
