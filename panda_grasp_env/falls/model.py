"""Fall dynamics: a ConvLSTM encoder-decoder that predicts the next segmentation frame of a falling tower.

Input: the past ``context`` frames as one-hot class maps (background + one class
per block colour, ``panda_grasp_env/falls/dataset.py``).  Five convolutions encode each
frame to a quarter-resolution feature map, a ConvLSTM carries the motion, and
five convolutions decode correction logits, with skip connections from the
newest frame's encoder features.  Blocks mostly translate between frames, so
each block's channel of the newest frame is shifted, as a whole, by that
block's predicted displacement: its own velocity (the centroid step from the
frame before, computed from the inputs: constant velocity) plus a correction
from a small motion network that reads the block's last ``MOTION_HISTORY``
steps (velocity, visible area and, with depth, mean height, each with its
change) and the ConvLSTM's features pooled over the block (contacts,
landings).  The correction logits add what translation cannot (rotation,
occlusion, blocks coming into view).  Untrained, the model is
constant-velocity extrapolation with soft edges.  Multi-step rollouts feed the
predicted class probabilities back in (their centroids give the next velocity).

With ``use_depth`` each input frame also carries a height map (``heights``:
block units above the frame's lowest surface, from the depth image): a top view
of class masks cannot tell a block about to land from one still falling.  The
model then also predicts the next height map (each block's heights carried by
its warp, plus a learned correction), which multi-step rollouts feed back.

Metrics (``evaluate``), over every evaluated (sequence, t) of a split, for the
prediction of frame t + h from frames t - context + 1 ... t:

* pixel accuracy: predicted class == true class, over all pixels;
* foreground accuracy: the same over pixels whose *true* class is a block;
* IoU of class c: sum of |pred = c and true = c| / sum of |pred = c or true = c|
  over all evaluated frames (dataset-level); mean block IoU: mean over the block classes.

Baselines: ``copy_last`` (frame t is the prediction) and ``constant_velocity``
(each block's mask at t shifted by h times its centroid displacement from t - 1 to t).
Reference, not a predictor: ``translation_oracle`` shifts each block's mask at t by
its true centroid displacement to t + h -- the ceiling of mask translation.

Fall direction (``fall_directions``): which way each tower fell, from its block
poses, against the direction of the block pixels' centroid in each predictor's
last frame, predicted from the first frames.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any

import numpy as np
import torch
import torch.nn.functional as F
from torch import nn

from panda_grasp_env.perception.camera import CameraModel

#: Changes whenever the same weights would mean another model; saved in checkpoints and checked on load.
ARCHITECTURE = 3
#: Steps of each block's motion the motion network reads.
MOTION_HISTORY = 3
#: Metres of height per unit of a height map (one block's edge).
HEIGHT_UNIT = 0.05


def conv(in_channels: int, out_channels: int, stride: int = 1) -> nn.Sequential:
    return nn.Sequential(nn.Conv2d(in_channels, out_channels, 3, stride, 1), nn.GroupNorm(4, out_channels), nn.ReLU())


class ConvLSTMCell(nn.Module):
    """LSTM gates computed by one 5x5 convolution over [input, hidden] (Shi et al. 2015)."""

    def __init__(self, channels: int, hidden: int) -> None:
        super().__init__()
        self.hidden = hidden
        self.gates = nn.Conv2d(channels + hidden, 4 * hidden, 5, padding=2)  # 5x5 at 1/4 scale: +-8 px of motion

    def forward(
        self, x: torch.Tensor, state: tuple[torch.Tensor, torch.Tensor] | None
    ) -> tuple[torch.Tensor, torch.Tensor]:
        if state is None:
            zeros = x.new_zeros(x.shape[0], self.hidden, *x.shape[2:])
            state = (zeros, zeros)
        h, c = state
        i, f, o, g = self.gates(torch.cat([x, h], 1)).chunk(4, 1)
        c = torch.sigmoid(f) * c + torch.sigmoid(i) * torch.tanh(g)
        h = torch.sigmoid(o) * torch.tanh(c)
        return h, c


class FallPredictor(nn.Module):
    """Next-frame class logits from a sequence of frames (B, T, C [+ 1], S, S): class probabilities, then
    with ``use_depth`` a height map (``model_inputs`` builds them)."""

    def __init__(
        self, n_classes: int, image_size: int, context: int, hidden: int = 32, use_depth: bool = False
    ) -> None:
        super().__init__()
        if image_size % 4:
            raise ValueError(f"image_size must be a multiple of 4, got {image_size}")
        self.n_classes, self.image_size, self.context, self.hidden = n_classes, image_size, context, hidden
        self.use_depth = use_depth
        channels = n_classes + int(use_depth)
        self.e1, self.e2, self.e3 = conv(2 * channels, 16), conv(16, 32, 2), conv(32, 32)  # frame and its predecessor
        self.e4, self.e5 = conv(32, 64, 2), conv(64, 64)
        self.lstm = ConvLSTMCell(64, hidden)
        self.d1 = conv(hidden + 64, 64)
        self.d2 = conv(64 + 32, 32)
        self.d3 = conv(32, 32)
        self.d4 = conv(32 + 16, 16)
        self.d5 = nn.Conv2d(16, channels, 3, padding=1)  # correction logits [, heights]
        self.block_features = 4 + 2 * int(use_depth)  # see block_descriptors
        self.motion = nn.Sequential(
            nn.Linear(MOTION_HISTORY * self.block_features + hidden, 128),
            nn.ReLU(),
            nn.Linear(128, 128),
            nn.ReLU(),
            nn.Linear(128, 2),
        )
        for layer in (self.d5, self.motion[-1]):  # starts as constant-velocity extrapolation
            nn.init.zeros_(layer.weight)
            nn.init.zeros_(layer.bias)
        self.copy_gain = nn.Parameter(torch.tensor(1.0))
        axis = (torch.arange(image_size, dtype=torch.float32) + 0.5) / image_size * 2 - 1
        rows, cols = torch.meshgrid(axis, axis, indexing="ij")
        self.register_buffer("grid", torch.stack([cols, rows], -1)[None], persistent=False)

    def block_descriptors(self, frame: torch.Tensor, previous: torch.Tensor) -> torch.Tensor:
        """(B, K, F) of each block class from its probability mass in ``frame`` and ``previous`` (B, C [+ 1], S, S):
        velocity (x, y: centroid step in pixels, zero for a block with under a pixel of mass in either frame),
        visible area (hundreds of pixels) and its change, and with ``use_depth`` mean height (blocks) and its
        change."""

        def measure(frames: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor]:
            masks = frames[:, 1 : self.n_classes]
            centre, mass = mask_centroids(masks)
            height = (masks * frames[:, self.n_classes :]).sum((2, 3)) / mass.clamp_min(1e-6) if self.use_depth \
                else mass.new_zeros(0)  # fmt: skip
            return centre, mass, height

        (now, mass_now, height_now), (before, mass_before, height_before) = measure(frame), measure(previous)
        seen = ((mass_now > 1.0) & (mass_before > 1.0)).float()
        features = [
            (now - before) * seen[..., None],
            mass_now[..., None] / 100,
            (mass_now - mass_before)[..., None] / 100,
        ]
        if self.use_depth:
            features += [height_now[..., None], ((height_now - height_before) * seen)[..., None]]
        return torch.cat(features, 2)

    def step(
        self, frame: torch.Tensor, previous: torch.Tensor, state: Any
    ) -> tuple[torch.Tensor, torch.Tensor, Any, torch.Tensor | None]:
        """Consume one frame (B, C [+ 1], S, S) (with the one before it, so that the first convolutions see
        motion directly); logits of the next frame, each block's displacement (B, K, 2) that moved it (pixels,
        x = column then y = row), the new state and, with ``use_depth``, the next height map (B, 1, S, S)."""
        f1 = self.e1(torch.cat([frame, previous], 1))
        f3 = self.e3(self.e2(f1))
        f5 = self.e5(self.e4(f3))
        h, c = self.lstm(f5, None if state is None else state[:2])
        x = self.d1(torch.cat([h, f5], 1))
        x = self.d3(self.d2(torch.cat([F.interpolate(x, scale_factor=2.0), f3], 1)))
        out = self.d5(self.d4(torch.cat([F.interpolate(x, scale_factor=2.0), f1], 1)))
        batch, blocks, size, n = frame.shape[0], self.n_classes - 1, self.image_size, self.n_classes
        descriptors = self.block_descriptors(frame, previous)
        history = descriptors.new_zeros(batch, blocks, MOTION_HISTORY, self.block_features) if state is None \
            else state[2]  # fmt: skip
        history = torch.cat([history[:, :, 1:], descriptors[:, :, None]], 2)
        coarse = F.avg_pool2d(frame[:, 1:n], size // h.shape[-1])  # block masks at the ConvLSTM's resolution
        pooled = torch.einsum("bkhw,bchw->bkc", coarse, h) / coarse.sum((2, 3)).clamp_min(1e-3)[..., None]
        displacement = descriptors[..., :2] + self.motion(torch.cat([history.flatten(2), pooled], 2))
        # Block k's channel of the next frame at p is drawn from this frame's at p - displacement[k].
        grids = self.grid[:, None] - displacement[:, :, None, None, :] * (2.0 / size)  # pixels -> grid units
        masks = frame[:, 1:n, None]  # (B, K, 1, S, S); with depth each block also carries its heights
        carried = torch.cat([masks, masks * frame[:, n:, None]], 2) if self.use_depth else masks
        moved = F.grid_sample(
            carried.reshape(batch * blocks, carried.shape[2], size, size),
            grids.expand(batch, blocks, size, size, 2).reshape(batch * blocks, size, size, 2),
            mode="bilinear",
            padding_mode="zeros",
            align_corners=False,
        ).view(batch, blocks, carried.shape[2], size, size)
        warped = torch.cat([(1.0 - moved[:, :, 0].sum(1, keepdim=True)).clamp_min(0.0), moved[:, :, 0]], 1)
        logits = self.copy_gain * torch.log(warped + 0.1) + out[:, :n]
        heights = moved[:, :, 1].sum(1, keepdim=True) + out[:, n:] if self.use_depth else None
        return logits, displacement, (h, c, history), heights

    def rollout_with_motion(
        self, frames: torch.Tensor, horizon: int
    ) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor | None]:
        """Logits (B, horizon, C, S, S) of the ``horizon`` frames after ``frames`` (B, T, C [+ 1], S, S), the
        block displacements (B, horizon, K, 2) that produced them (see ``step``) and, with ``use_depth``, the
        predicted height maps (B, horizon, 1, S, S)."""
        if frames.shape[2] != self.n_classes + int(self.use_depth):
            raise ValueError(
                f"frames have {frames.shape[2]} channels; this model reads {self.n_classes} classes"
                + (" and a height map" if self.use_depth else "")
            )
        state, logits, motion, heights = None, None, None, None
        for t in range(frames.shape[1]):
            logits, motion, state, heights = self.step(frames[:, t], frames[:, max(t - 1, 0)], state)
        outputs, motions, all_heights, previous = [logits], [motion], [heights], frames[:, -1]
        for _ in range(horizon - 1):
            frame = torch.softmax(logits, 1)
            if self.use_depth:
                frame = torch.cat([frame, heights], 1)
            logits, motion, state, heights = self.step(frame, previous, state)
            outputs.append(logits)
            motions.append(motion)
            all_heights.append(heights)
            previous = frame
        stacked_heights = torch.stack(all_heights, 1) if self.use_depth else None
        return torch.stack(outputs, 1), torch.stack(motions, 1), stacked_heights

    def rollout(self, frames: torch.Tensor, horizon: int) -> torch.Tensor:
        """Logits (B, horizon, C, S, S) of the ``horizon`` frames after ``frames`` (B, T, C [+ 1], S, S)."""
        return self.rollout_with_motion(frames, horizon)[0]

    def describe(self) -> dict[str, int]:
        return {
            "n_classes": self.n_classes,
            "image_size": self.image_size,
            "context": self.context,
            "hidden": self.hidden,
            "use_depth": self.use_depth,
        }


def mask_centroids(masks: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
    """Centroids (B, K, 2) in pixels (x = column, y = row) and masses (B, K) of masks (B, K, S, S), hard or
    soft; a centroid is zero where its mask is empty."""
    mass = masks.sum((2, 3))
    pixels = torch.arange(masks.shape[-1], dtype=masks.dtype, device=masks.device)
    x = (masks.sum(2) * pixels).sum(2) / mass.clamp_min(1e-6)
    y = (masks.sum(3) * pixels).sum(2) / mass.clamp_min(1e-6)
    return torch.stack([x, y], 2), mass


def one_hot(labels: torch.Tensor, n_classes: int) -> torch.Tensor:
    """(..., S, S) integer labels -> (..., C, S, S) float one-hot."""
    return F.one_hot(labels.long(), n_classes).movedim(-1, -3).float()


def heights(depth: torch.Tensor) -> torch.Tensor:
    """(..., S, S) depth images (metres along the optical axis of a top-down camera) -> (..., 1, S, S) heights
    above each frame's lowest (deepest) surface, in blocks (``HEIGHT_UNIT``)."""
    depth = depth.float()
    return ((depth.amax((-2, -1), keepdim=True) - depth) / HEIGHT_UNIT).unsqueeze(-3)


def model_inputs(model: FallPredictor, labels: Any, depth: Any = None) -> torch.Tensor:
    """The model's frames (B, T, C [+ 1], S, S) from labels (B, T, S, S) and, for a ``use_depth`` model,
    depth images of the same frames (``ValueError`` without them)."""
    frames = one_hot(torch.as_tensor(labels), model.n_classes)
    if not model.use_depth:
        return frames
    if depth is None:
        raise ValueError("this model reads depth images with its labels; load the split with depth=True")
    return torch.cat([frames, heights(torch.as_tensor(depth))], -3)


def block_displacements(before: torch.Tensor, after: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
    """Each block's centroid displacement (B, K, 2) in pixels (x, y) between true labels (B, S, S) of two
    consecutive frames -- what the model's displacement should be -- and each block's area in ``after``
    (B, K), zero where the block is missing from either frame (no displacement defined)."""
    n_classes = int(max(before.max(), after.max())) + 1
    start, area_before = mask_centroids(one_hot(before, n_classes)[:, 1:])
    end, area_after = mask_centroids(one_hot(after, n_classes)[:, 1:])
    return end - start, area_after * (area_before > 0)


def check_compatible(model: FallPredictor, labels: np.ndarray, classes: list[str], depth: Any = None) -> None:
    """``ValueError`` if a dataset's images or classes do not match what the model was trained on (or it reads
    depth and none is given)."""
    if model.use_depth and (depth is None or np.shape(depth) != np.shape(labels)):
        shape = None if depth is None else np.shape(depth)
        raise ValueError(f"model reads depth images shaped like its labels {np.shape(labels)}; got {shape}")
    if labels.shape[-1] != model.image_size or labels.shape[-2] != model.image_size:
        raise ValueError(f"model expects {model.image_size}x{model.image_size} frames, dataset has {labels.shape[-2:]}")
    if len(classes) != model.n_classes:
        raise ValueError(f"model predicts {model.n_classes} classes, dataset has {len(classes)}: {classes}")
    if labels.size and int(labels.max()) >= model.n_classes:
        raise ValueError(f"dataset labels reach {int(labels.max())}, the model knows classes 0-{model.n_classes - 1}")


# --- baselines ----------------------------------------------------------------------------------


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


# --- metrics -------------------------------------------------------------------------------------


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


def predict_batch(
    model: FallPredictor, windows: np.ndarray, horizon: int, depth: np.ndarray | None = None
) -> np.ndarray:
    """Predicted labels (B, horizon, S, S) after context windows (B, K, S, S) of labels (and of depth images,
    for a ``use_depth`` model)."""
    with torch.no_grad():
        return model.rollout(model_inputs(model, windows, depth), horizon).argmax(2).numpy().astype(np.uint8)


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


# --- fall direction ------------------------------------------------------------------------------

#: Horizontal shift (m) of a tower's mean block position, first frame to last, below which it did not fall.
FALL_SHIFT = 0.02
#: Predicted shift (pixels) of the block pixels' centroid below which a prediction gives no direction.
DIRECTION_MIN_PIXELS = 0.5
#: Angular error (degrees) up to which a predicted fall direction counts as right (``within_45`` of the results).
DIRECTION_TOLERANCE = 45.0


def image_to_world_direction(shift: np.ndarray, camera: dict[str, Any]) -> np.ndarray:
    """World-frame horizontal vectors (..., 2) (x, y) along image displacements ``shift`` (..., 2) (rows,
    columns; pixels) of a straight-down camera (``camera``: ``K``, and ``rotation`` camera -> world in OpenCV
    axes, as ``metadata.json`` holds them): each displacement as the camera-frame vector (columns / fx,
    rows / fy, 0) turned into the world.  A direction only: the length depends on depth, and parallax (points
    nearing the principal point as they fall away from the camera) is ignored."""
    K, rotation = np.asarray(camera["K"], dtype=float), np.asarray(camera["rotation"], dtype=float)
    shift = np.asarray(shift, dtype=float)
    along = np.stack([shift[..., 1] / K[0, 0], shift[..., 0] / K[1, 1], np.zeros(shift.shape[:-1])], -1)
    return (along @ rotation.T)[..., :2]


def angle_between(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """Unsigned angles (degrees, 0-180) between 2-D vectors ``a`` and ``b`` (..., 2)."""
    turn = np.arctan2(a[..., 1], a[..., 0]) - np.arctan2(b[..., 1], b[..., 0])
    return np.degrees(np.abs((turn + np.pi) % (2 * np.pi) - np.pi))


def fall_directions(
    model: FallPredictor | None,
    labels: np.ndarray,
    poses: np.ndarray,
    n_blocks: np.ndarray,
    crop_origin: np.ndarray,
    camera: dict[str, Any],
    classes: list[str],
    context: int,
    depth: np.ndarray | None = None,
    batch_size: int = 64,
) -> dict[str, Any]:
    """Which way each tower fell, predicted from its first frames, against what happened.

    Sequences: ``labels`` (N, T, S, S) cut at ``crop_origin`` (N, 2) (column, row) from the renders of the
    overhead ``camera`` of ``metadata.json`` (``render_size``, ``K``, ``rotation``, ``position``), block
    ``poses`` (N, T, B, 7) (world frame, metres; rows past a sequence's ``n_blocks`` are ignored); ``depth``
    (N, T, S, S) for a ``use_depth`` model.  With t = max(context - 1, 1), the newest context frame as in
    ``evaluate``:

    * true direction: the horizontal (x, y) displacement, in the world frame, of the mean position of the
      sequence's blocks from frame 0 to frame T - 1, over the blocks whose centre lies inside the crop in
      frame T - 1.  A tower whose mean moved under ``FALL_SHIFT`` did not fall: it is counted in
      ``did_not_fall`` and not scored (so is a tower that stood while a struck block flew out of view).  The
      world frame and the poses, not the images, because they say where the blocks went: the pixels see
      only the blocks' visible faces, and the top of a tall tower seen from above sits off its base by
      parallax.
    * predicted direction: the centroid of every block pixel (any block class) of the predictor's frame
      T - 1, predicted from frames up to t (the model rolled out T - 1 - t steps from frames
      t - context + 1 ... t; a baseline of ``BASELINES`` called with (t, T - 1 - t)), minus the centroid of
      the block pixels of the true frame 0, in image coordinates, turned into a world direction by
      ``image_to_world_direction``.  A fallen tower of whose blocks frame 0 shows no pixel (the arm of a
      push above it) gives no predictor a place to start: it is counted in ``hidden`` and not scored.  Under
      ``DIRECTION_MIN_PIXELS`` of shift, or with no block pixel in the predicted frame, a prediction has no
      direction: counted in ``no_direction`` and scored as 180 degrees.
    * ``true_labels``, a reference rather than a predictor: the true frame T - 1 through the same mapping,
      what a perfect segmentation predictor scores; its shortfall is the mapping's (occlusion, parallax,
      blocks leaving the crop).

    Per predictor, over the ``scored`` sequences (the tower fell and frame 0 shows it): ``within_45``, the
    fraction whose angular error is at most ``DIRECTION_TOLERANCE`` degrees, and ``median_error_deg``.  The
    summary covers all sequences and, where they hold several tower heights, each height (``by_height``,
    keyed by the number of blocks).
    """
    n, length = labels.shape[:2]
    t = max(context - 1, 1)
    horizon = length - 1 - t
    if horizon < 1:
        raise ValueError(f"sequences of {length} frames leave nothing to predict after context {context}")
    ends = {name: np.stack([baseline(labels[i], t, horizon) for i in range(n)]) for name, baseline in BASELINES.items()}
    if model is not None:
        check_compatible(model, labels, classes, depth)
        model.eval()
        windows = labels[:, t - context + 1 : t + 1]
        contexts = depth[:, t - context + 1 : t + 1] if model.use_depth else None
        ends["model"] = np.concatenate([
            predict_batch(model, windows[b : b + batch_size], horizon,
                          None if contexts is None else contexts[b : b + batch_size])[:, -1]
            for b in range(0, n, batch_size)
        ])  # fmt: skip
    ends["true_labels"] = labels[:, -1]
    start = [centroid(frame > 0) for frame in labels[:, 0]]
    view = CameraModel(
        *camera["render_size"], *(np.asarray(camera[k], dtype=float) for k in ("K", "rotation", "position"))
    )
    truth = np.zeros((n, 2))
    for i in range(n):
        blocks = poses[i, :, : n_blocks[i], :3]
        pixels = view.world_to_pixel(blocks[-1])[0] - crop_origin[i]  # (column, row) in the crop
        seen = np.all((pixels >= -0.5) & (pixels < labels.shape[-1] - 0.5), axis=1)
        if seen.any():
            truth[i] = (blocks[-1, seen, :2] - blocks[0, seen, :2]).mean(0)
    fell = np.hypot(*truth.T) >= FALL_SHIFT
    errors = {}
    for name, frames in ends.items():
        error = np.full(n, np.nan)  # NaN: no direction
        for i, frame in enumerate(frames):
            end = centroid(frame > 0)
            if start[i] is not None and end is not None and np.hypot(*(end - start[i])) >= DIRECTION_MIN_PIXELS:
                error[i] = angle_between(image_to_world_direction(end - start[i], camera), truth[i])
        errors[name] = error

    seen = np.array([first is not None for first in start])

    def summary(chosen: np.ndarray) -> dict[str, Any]:
        scored = chosen & fell & seen
        predictors = {}
        for name, error in errors.items():
            worst = np.where(np.isnan(error[scored]), 180.0, error[scored])
            predictors[name] = {
                "within_45": round(float(np.mean(worst <= DIRECTION_TOLERANCE)), 4) if scored.any() else None,
                "median_error_deg": round(float(np.median(worst)), 1) if scored.any() else None,
                "no_direction": int(np.isnan(error[scored]).sum()),
            }
        return {"sequences": int(chosen.sum()), "did_not_fall": int((chosen & ~fell).sum()),
                "fell": int((chosen & fell).sum()), "hidden": int((chosen & fell & ~seen).sum()),
                "scored": int(scored.sum()), "predictors": predictors}  # fmt: skip

    result = summary(np.ones(n, dtype=bool))
    heights = np.unique(n_blocks)
    if len(heights) > 1:
        result["by_height"] = {str(int(h)): summary(n_blocks == h) for h in heights}
    return result
