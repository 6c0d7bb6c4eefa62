"""The settle head: will what was just set stand?  Its data, its fitting and its scores.

A structure-fall sequence starts at rest, the moment a piece is set (``panda_grasp_env/falls/structure_falls.py``);
its recorded block poses say how far each block went by the last frame.  The settle head
(``model.SettleHead``) reads the first frame alone and predicts the largest of those displacements (metres,
world frame, the last frame's position minus the first's, as ``sim.stability.what_if`` measures it).  Fitted
on ``log1p`` of millimetres, so that a 0.5 mm settle and a 5 cm fall both count; scored as the stability check
uses it: "falls" where the prediction reaches ``STILL_SHIFT`` (4 mm), against the recording.
"""

from __future__ import annotations

import copy
import time
from typing import Any

import numpy as np
import torch
import torch.nn.functional as F

from panda_grasp_env.agents.learning.falls.dataset import FallSequences
from panda_grasp_env.agents.learning.falls.model import FallPredictor, model_inputs
from panda_grasp_env.sim.stability import STILL_SHIFT


def largest_shifts(split: FallSequences, frames: int) -> np.ndarray:
    """(N,) metres: the largest displacement of any of each sequence's blocks from its first frame to frame
    ``frames``."""
    if not 1 <= frames < split.poses.shape[1]:
        raise ValueError(f"frames must be in 1..{split.poses.shape[1] - 1} (the sequences' length - 1), got {frames}")
    moved = np.linalg.norm(split.poses[:, frames, :, :3] - split.poses[:, 0, :, :3], axis=2)  # NaN past n_blocks
    kept = np.arange(moved.shape[1])[None] < split.n_blocks[:, None]
    return np.where(kept, np.nan_to_num(moved, nan=0.0), 0.0).max(1)


def first_frames(model: FallPredictor, split: FallSequences, rows: np.ndarray | slice) -> torch.Tensor:
    """The model's input frames (B, C [+ 1], S, S) of the first frame of the sequences ``rows``."""
    depth = split.depth[rows, :1] if model.use_depth else None
    return model_inputs(model, split.labels[rows, :1], depth)[:, 0]


def predicted_shifts(model: FallPredictor, split: FallSequences, batch_size: int = 256) -> np.ndarray:
    """(N,) metres: the settle head's prediction for each sequence's first frame."""
    shifts = []
    with torch.no_grad():
        for first in range(0, len(split.labels), batch_size):
            shifts.append(model.settle_shift(first_frames(model, split, slice(first, first + batch_size))))
    return torch.cat(shifts).numpy()


def classification(predicted: np.ndarray, falls: np.ndarray, threshold: float = STILL_SHIFT) -> dict[str, Any]:
    """Precision, recall and accuracy of "falls" (``predicted`` displacements >= ``threshold`` metres) against
    the truth ``falls`` (booleans), with the accuracy of always answering "stands" beside them."""
    falls, said = np.asarray(falls, dtype=bool), np.asarray(predicted) >= threshold
    hits = int(np.sum(falls & said))
    return {
        "sequences": int(len(falls)),
        "falls": int(falls.sum()),
        "said_falls": int(said.sum()),
        "precision": round(hits / max(int(said.sum()), 1), 4),
        "recall": round(hits / max(int(falls.sum()), 1), 4),
        "accuracy": round(float(np.mean(falls == said)), 4),
        "always_stands_accuracy": round(float(np.mean(~falls)), 4),
    }


def settle_scores(model: FallPredictor, split: FallSequences) -> dict[str, Any]:
    """``classification`` of the settle head on every sequence of ``split`` at ``STILL_SHIFT``."""
    return classification(predicted_shifts(model, split), largest_shifts(split, model.settle_frames) >= STILL_SHIFT)


def dihedral(frames: torch.Tensor, k: int) -> torch.Tensor:
    """``frames`` (B, C, S, S) under the k-th of the square's 8 symmetries (a quarter turn k % 4 times, then a
    mirror for k >= 4): gravity is along the overhead camera's axis, so a structure turned or mirrored about
    it falls the same way turned or mirrored, and the largest displacement is the same."""
    turned = torch.rot90(frames, k % 4, (2, 3))
    return turned.flip(3) if k >= 4 else turned


def fit_settle_head(
    model: FallPredictor, train: FallSequences, val: FallSequences, epochs: int, batch_size: int = 64
) -> dict[str, Any]:
    """Fit ``model.settle`` alone (Adam 1e-3 on a cosine schedule, smooth L1 on ``log1p`` millimetres, each
    batch under a random ``dihedral`` symmetry) on the first frames of ``train``, keep the epoch of least
    loss on ``val``'s, and freeze it.  Returns each epoch's validation loss, the kept epoch's validation
    ``classification`` and the seconds spent."""
    began = time.perf_counter()
    head = model.settle
    frames = first_frames(model, train, slice(None))
    target = torch.log1p(torch.as_tensor(largest_shifts(train, model.settle_frames), dtype=torch.float32) * 1e3)
    val_frames = first_frames(model, val, slice(None))
    val_truth = largest_shifts(val, model.settle_frames)
    val_target = torch.log1p(torch.as_tensor(val_truth, dtype=torch.float32) * 1e3)
    head.requires_grad_(True)
    optimiser = torch.optim.Adam(head.parameters(), lr=1e-3)
    schedule = torch.optim.lr_scheduler.CosineAnnealingLR(optimiser, epochs)
    losses, best, kept = [], float("inf"), 0
    best_state = copy.deepcopy(head.state_dict())
    for epoch in range(epochs):
        head.train()
        for batch in torch.randperm(len(frames)).split(batch_size):
            k = int(torch.randint(8, ()))
            loss = F.smooth_l1_loss(head(dihedral(frames[batch], k)), target[batch])
            optimiser.zero_grad()
            loss.backward()
            optimiser.step()
        schedule.step()
        head.eval()
        with torch.no_grad():
            losses.append(round(float(F.smooth_l1_loss(head(val_frames), val_target)), 4))
        if losses[-1] < best:
            best, kept, best_state = losses[-1], epoch, copy.deepcopy(head.state_dict())
    head.load_state_dict(best_state)
    head.requires_grad_(False)  # and settle_shift below runs without building a graph
    return {
        "epochs": epochs,
        "training_sequences": len(frames),
        "validation_sequences": len(val_frames),
        "validation_loss": losses,
        "kept_epoch": kept,
        "validation": classification(model.settle_shift(val_frames).numpy(), val_truth >= STILL_SHIFT),
        "seconds": round(time.perf_counter() - began, 1),
    }
