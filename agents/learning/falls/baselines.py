"""What the fall-dynamics model is compared with: predictors that shift each block's mask, and a ceiling.

Each is called with a sequence's labels (T, S, S), the newest context frame ``t`` and the ``horizon``, and
returns the labels (S, S) it predicts for frame t + horizon.  ``copy_last``: frame t is the prediction;
``constant_velocity``: each block's mask at t shifted by ``horizon`` times its centroid displacement from
t - 1 to t.  Reference, not a predictor: ``translation_oracle`` shifts each block's mask at t by its true
centroid displacement to t + horizon -- the ceiling of mask translation.
"""

from __future__ import annotations

import numpy as np


def copy_last(labels: np.ndarray, t: int, horizon: int) -> np.ndarray:
    return labels[t]


def centroid(mask: np.ndarray) -> np.ndarray | None:
    """(row, column) mean of a boolean mask's pixels, or None if it is empty."""
    rows, cols = np.nonzero(mask)
    return np.array([rows.mean(), cols.mean()]) if len(rows) else None


def translate_blocks(frame: np.ndarray, displacement: dict[int, np.ndarray]) -> np.ndarray:
    """Each block's mask in ``frame`` moved by ``displacement[class]`` (rows, columns; rounded to pixels)."""
    size = frame.shape[0]
    moved = np.zeros_like(frame)
    for c, (dr, dc) in displacement.items():
        rows, cols = np.nonzero(frame == c)
        r = np.round(rows + dr).astype(int)
        k = np.round(cols + dc).astype(int)
        keep = (r >= 0) & (r < size) & (k >= 0) & (k < size)
        moved[r[keep], k[keep]] = c
    return moved


def displacements(frame: np.ndarray, other: np.ndarray) -> dict[int, np.ndarray]:
    """Centroid displacement from ``frame`` to ``other`` of each block in ``frame`` (zero if gone in ``other``)."""
    moves = {}
    for c in np.unique(frame[frame > 0]):
        start, end = centroid(frame == c), centroid(other == c)
        moves[int(c)] = np.zeros(2) if end is None else end - start
    return moves


def constant_velocity(labels: np.ndarray, t: int, horizon: int) -> np.ndarray:
    """Each block's mask at ``t`` moved by ``horizon`` times its centroid step from t - 1 to t."""
    steps = displacements(labels[t - 1], labels[t])
    current = displacements(labels[t], labels[t])  # every block at t, unmoved
    return translate_blocks(labels[t], {c: horizon * steps.get(c, zero) for c, zero in current.items()})


def translation_oracle(labels: np.ndarray, t: int, horizon: int) -> np.ndarray:
    """Not a predictor: each block's mask at ``t`` moved by its *true* centroid displacement to t + horizon.

    The best any pure mask translation can do; the gap to the truth is rotation, occlusion and blocks coming
    into view -- the ceiling of copy-and-shift predictors, reported beside the baselines."""
    return translate_blocks(labels[t], displacements(labels[t], labels[t + horizon]))


BASELINES = {"copy_last": copy_last, "constant_velocity": constant_velocity, "translation_oracle": translation_oracle}
