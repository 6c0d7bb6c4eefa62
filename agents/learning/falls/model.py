"""Fall dynamics: a ConvLSTM encoder-decoder that predicts the next segmentation frame of a falling tower.

Input: the past ``context`` frames as one-hot class maps (background + one class
per block colour, ``panda_grasp_env/falls/shards.py``).  Five convolutions encode each
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
An ``anchored`` model draws each predicted frame's blocks from the newest *true*
frame, shifted by the displacements summed so far, and reads back those shifted
blocks rather than its softmax: warping a warped prediction again blurs a
block's mask a little more each step, and the softmax's small share of every
class in every pixel, summed over a frame, drags each block's measured centroid
towards the middle (the first tall-tower model's rollouts ended empty).  Its
motion network predicts each displacement outright (the velocity is one of its
inputs), so untrained it copies the last frame: on tall towers a block's
centroid step jumps as blocks cover one another, and constant velocity five
frames on misses by 28 pixels on average against copying's 8.

An anchored model with a ``track_horizon`` plans instead: after the context
frames, a track head (``tracks``) reads every block's track over them -- its
centroid steps, visible area and mean height, and where each other block lies
and how it moves -- and gives each block's displacement to each of the next
``track_horizon`` frames at once, plus what a linear map of the ConvLSTM's
state pooled over the block adds; each predicted frame is the newest true
frame's blocks shifted by its planned displacement, and the ConvLSTM, reading
back the drawn frames, adds its correction logits.  Planning at once rather
than step by step keeps a rollout's errors from compounding, and the head can
be fitted alone on every training window's tracks before the ConvLSTM trains
(``training.pretrain_track_head``): a small network on tracks learns from far
more windows per minute than the ConvLSTM does.

With ``use_depth`` each input frame also carries a height map (``heights``:
block units above the frame's lowest surface, from the depth image): a top view
of class masks cannot tell a block about to land from one still falling.  The
model then also predicts the next height map (each block's heights carried by
its warp, plus a learned correction), which multi-step rollouts feed back.

With ``settle_frames`` the model also answers the stability check's question outright: a settle head
(``SettleHead``), a small convolutional network on the first frame alone, predicts the largest displacement
any block makes over the next ``settle_frames`` frames (metres).  It is fitted on each training sequence's first
frame against the recorded block poses (``training.fit_settle_head``): the track head plans motion from
blocks' tracks, and from one frame at rest those carry no motion to extend, so on structure falls it missed
about half the falls at 4 mm (docs/structures.md).

Here too: the model's inputs from labels and depth images, its predictions as labels, and its checkpoints'
loader.  The baselines it is compared with are in ``baselines``, its metrics in ``metrics`` and
``directions``.
"""

from __future__ import annotations

from pathlib import Path
from typing import Any

import numpy as np
import torch
import torch.nn.functional as F
from torch import nn

from panda_grasp_env.agents.learning.falls.tracks import (
    TrackHead,
    block_tracks,
    mask_centroids,
    track_feature_count,
    track_features,
)

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


class SettleHead(nn.Module):
    """From one frame at rest (B, C [+ 1], S, S), centred on the piece just set: ``log1p`` of the largest
    displacement (millimetres) any block makes over the frames that follow (B,).  Four strided convolutions keep
    where things lie relative to the centre (the candidate and what is under it), so the features are
    flattened, not pooled."""

    def __init__(self, channels: int, image_size: int) -> None:
        super().__init__()
        self.features = nn.Sequential(conv(channels, 16, 2), conv(16, 32, 2), conv(32, 64, 2), conv(64, 64, 2))
        cells = image_size
        for _ in range(4):
            cells = (cells + 1) // 2  # 3x3, stride 2, padding 1
        self.out = nn.Sequential(nn.Flatten(), nn.Linear(64 * cells * cells, 64), nn.ReLU(), nn.Linear(64, 1))

    def forward(self, frame: torch.Tensor) -> torch.Tensor:
        return self.out(self.features(frame))[:, 0]


class FallPredictor(nn.Module):
    """Next-frame class logits from a sequence of frames (B, T, C [+ 1], S, S): class probabilities, then
    with ``use_depth`` a height map (``model_inputs`` builds them)."""

    def __init__(
        self,
        n_classes: int,
        image_size: int,
        context: int,
        hidden: int = 32,
        use_depth: bool = False,
        anchored: bool = False,
        track_horizon: int = 0,
        settle_frames: int = 0,
    ) -> None:
        super().__init__()
        if image_size % 4:
            raise ValueError(f"image_size must be a multiple of 4, got {image_size}")
        if track_horizon < 0 or (track_horizon and not anchored):
            raise ValueError(f"track_horizon must be 0, or >= 1 with anchored=True; got {track_horizon}")
        self.n_classes, self.image_size, self.context, self.hidden = n_classes, image_size, context, hidden
        if settle_frames < 0:
            raise ValueError(f"settle_frames must be 0 (no settle head) or >= 1, got {settle_frames}")
        self.use_depth, self.anchored, self.track_horizon = use_depth, anchored, track_horizon
        self.settle_frames = settle_frames
        channels = n_classes + int(use_depth)
        if settle_frames:
            self.settle = SettleHead(channels, image_size)
        self.e1, self.e2, self.e3 = conv(2 * channels, 16), conv(16, 32, 2), conv(32, 32)  # frame and its predecessor
        self.e4, self.e5 = conv(32, 64, 2), conv(64, 64)
        self.lstm = ConvLSTMCell(64, hidden)
        self.d1 = conv(hidden + 64, 64)
        self.d2 = conv(64 + 32, 32)
        self.d3 = conv(32, 32)
        self.d4 = conv(32 + 16, 16)
        self.d5 = nn.Conv2d(16, channels, 3, padding=1)  # correction logits [, heights]
        if track_horizon:
            self.tracks = TrackHead(track_feature_count(context, n_classes - 1), track_horizon)
            self.pooled_motion = nn.Linear(hidden, 2 * track_horizon)  # what the ConvLSTM adds to the tracks' plan
            last_layers: tuple[nn.Module, ...] = (self.d5, self.pooled_motion)
        else:
            self.block_features = 4 + 2 * int(use_depth)  # see block_descriptors
            self.motion = nn.Sequential(
                nn.Linear(MOTION_HISTORY * self.block_features + hidden, 128),
                nn.ReLU(),
                nn.Linear(128, 128),
                nn.ReLU(),
                nn.Linear(128, 2),
            )
            last_layers = (self.d5, self.motion[-1])
        for layer in last_layers:  # starts as constant-velocity extrapolation (anchored: copying the last frame)
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
        centre, mass, height = block_tracks(torch.stack([previous, frame], 1), self.n_classes)
        before, now = centre.unbind(1)
        mass_before, mass_now = mass.unbind(1)
        height_before, height_now = height.unbind(1)
        seen = ((mass_now > 1.0) & (mass_before > 1.0)).float()
        features = [
            (now - before) * seen[..., None],
            mass_now[..., None] / 100,
            (mass_now - mass_before)[..., None] / 100,
        ]
        if self.use_depth:
            features += [height_now[..., None], ((height_now - height_before) * seen)[..., None]]
        return torch.cat(features, 2)

    def advance(
        self, frame: torch.Tensor, previous: torch.Tensor, state: tuple[torch.Tensor, torch.Tensor] | None
    ) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor]:
        """Consume one frame (B, C [+ 1], S, S) (with the one before it, so that the first convolutions see
        motion directly): the ConvLSTM's new hidden and cell states and the decoder's correction logits [and
        heights] of the next frame (B, C [+ 1], S, S)."""
        f1 = self.e1(torch.cat([frame, previous], 1))
        f3 = self.e3(self.e2(f1))
        f5 = self.e5(self.e4(f3))
        h, c = self.lstm(f5, state)
        x = self.d1(torch.cat([h, f5], 1))
        x = self.d3(self.d2(torch.cat([F.interpolate(x, scale_factor=2.0), f3], 1)))
        return h, c, self.d5(self.d4(torch.cat([F.interpolate(x, scale_factor=2.0), f1], 1)))

    def pooled(self, frame: torch.Tensor, h: torch.Tensor) -> torch.Tensor:
        """(B, K, hidden): the ConvLSTM's state ``h`` averaged over each block's mask in ``frame`` (contacts,
        landings)."""
        coarse = F.avg_pool2d(frame[:, 1 : self.n_classes], self.image_size // h.shape[-1])
        return torch.einsum("bkhw,bchw->bkc", coarse, h) / coarse.sum((2, 3)).clamp_min(1e-3)[..., None]

    def draw(
        self, anchor: torch.Tensor, shift: torch.Tensor, out: torch.Tensor
    ) -> tuple[torch.Tensor, torch.Tensor | None, torch.Tensor]:
        """The next frame: its logits, with ``use_depth`` its height map (B, 1, S, S), and the shifted blocks
        alone (B, C, S, S: class probabilities without the correction logits).  Block k's channel at p is
        ``anchor``'s at p - ``shift``[k] (B, K, 2; pixels, x then y), plus the correction logits ``out``."""
        batch, blocks, size, n = anchor.shape[0], self.n_classes - 1, self.image_size, self.n_classes
        grids = self.grid[:, None] - shift[:, :, None, None, :] * (2.0 / size)  # pixels -> grid units
        masks = anchor[:, 1:n, None]  # (B, K, 1, S, S); with depth each block also carries its heights
        carried = torch.cat([masks, masks * anchor[:, n:, None]], 2) if self.use_depth else masks
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
        return logits, heights, warped

    def step(
        self,
        frame: torch.Tensor,
        previous: torch.Tensor,
        state: Any,
        anchor: torch.Tensor | None = None,
        moved_so_far: torch.Tensor | None = None,
    ) -> tuple[torch.Tensor, torch.Tensor, Any, torch.Tensor | None, torch.Tensor]:
        """A model without a track head: consume one frame (B, C [+ 1], S, S) (``advance``); logits of the
        next frame, each block's displacement (B, K, 2) that moved it (pixels, x = column then y = row), the
        new state, with ``use_depth`` the next height map (B, 1, S, S), and the shifted blocks alone (``draw``).

        The next frame's blocks are ``anchor``'s (default: ``frame``) shifted by ``moved_so_far`` (B, K, 2;
        default none) plus this step's displacement: a rollout anchors on its newest true frame."""
        h, c, out = self.advance(frame, previous, None if state is None else state[:2])
        batch, blocks = frame.shape[0], self.n_classes - 1
        descriptors = self.block_descriptors(frame, previous)
        history = (
            descriptors.new_zeros(batch, blocks, MOTION_HISTORY, self.block_features) if state is None else state[2]
        )
        history = torch.cat([history[:, :, 1:], descriptors[:, :, None]], 2)
        correction = self.motion(torch.cat([history.flatten(2), self.pooled(frame, h)], 2))
        displacement = correction if self.anchored else descriptors[..., :2] + correction
        anchor = frame if anchor is None else anchor
        shift = displacement if moved_so_far is None else moved_so_far + displacement
        logits, heights, warped = self.draw(anchor, shift, out)
        return logits, displacement, (h, c, history), heights, warped

    def track_plan(self, frames: torch.Tensor, h: torch.Tensor) -> torch.Tensor:
        """(B, track_horizon, K, 2): each block's displacement (pixels, x then y) from the newest of ``frames``
        (B, T, C [+ 1], S, S) to each next frame, from the blocks' tracks (``tracks``) plus what the ConvLSTM's
        state ``h`` after them adds over each block."""
        centre, area, height = block_tracks(frames, self.n_classes)
        planned = self.tracks(track_features(centre, area, height, self.image_size))
        extra = self.pooled_motion(self.pooled(frames[:, -1], h)).view_as(planned)
        return (planned + extra).transpose(1, 2)

    def rollout_tracks(
        self, frames: torch.Tensor, horizon: int
    ) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor | None]:
        """``rollout_with_motion`` of a model with a track head: the displacements to every predicted frame
        are planned once, after the context frames; the ConvLSTM reads back each drawn frame for its
        correction logits."""
        if horizon > self.track_horizon:
            raise ValueError(f"horizon {horizon} is past this model's track_horizon ({self.track_horizon} frames)")
        state = None
        for t in range(frames.shape[1]):
            *state, out = self.advance(frames[:, t], frames[:, max(t - 1, 0)], state)
        plan = self.track_plan(frames, state[0])[:, :horizon]
        anchor = previous = frames[:, -1]
        logits, heights, drawn = self.draw(anchor, plan[:, 0], out)
        outputs, all_heights = [logits], [heights]
        for k in range(1, horizon):
            frame = drawn if heights is None else torch.cat([drawn, heights], 1)
            *state, out = self.advance(frame, previous, state)
            logits, heights, drawn = self.draw(anchor, plan[:, k], out)
            outputs.append(logits)
            all_heights.append(heights)
            previous = frame
        steps = torch.diff(plan, dim=1, prepend=torch.zeros_like(plan[:, :1]))
        return torch.stack(outputs, 1), steps, torch.stack(all_heights, 1) if self.use_depth else None

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
        if self.track_horizon:
            return self.rollout_tracks(frames, horizon)
        state, logits, motion, heights = None, None, None, None
        for t in range(frames.shape[1]):
            logits, motion, state, heights, drawn = self.step(frames[:, t], frames[:, max(t - 1, 0)], state)
        anchor = frames[:, -1] if self.anchored else None
        outputs, motions, all_heights, previous, moved = [logits], [motion], [heights], frames[:, -1], motion
        for _ in range(horizon - 1):
            # An anchored model reads back its shifted blocks: the softmax leaks a little of every class into
            # every pixel, and over a whole frame that mass pulls each block's centroid towards the middle.
            frame = drawn if self.anchored else torch.softmax(logits, 1)
            if self.use_depth:
                frame = torch.cat([frame, heights], 1)
            logits, motion, state, heights, drawn = self.step(
                frame, previous, state, anchor, moved if self.anchored else None
            )
            moved = moved + motion
            outputs.append(logits)
            motions.append(motion)
            all_heights.append(heights)
            previous = frame
        stacked_heights = torch.stack(all_heights, 1) if self.use_depth else None
        return torch.stack(outputs, 1), torch.stack(motions, 1), stacked_heights

    def rollout(self, frames: torch.Tensor, horizon: int) -> torch.Tensor:
        """Logits (B, horizon, C, S, S) of the ``horizon`` frames after ``frames`` (B, T, C [+ 1], S, S)."""
        return self.rollout_with_motion(frames, horizon)[0]

    def settle_shift(self, frame: torch.Tensor) -> torch.Tensor:
        """(B,) the largest displacement (metres) the settle head predicts of any block over the next
        ``settle_frames`` frames after ``frame`` (B, C [+ 1], S, S), a frame at rest."""
        if not self.settle_frames:
            raise ValueError("this fall model has no settle head (trained with settle_epochs: 0)")
        return torch.expm1(self.settle(frame).clamp_min(0.0)) * 1e-3

    def describe(self) -> dict[str, int]:
        return {
            "n_classes": self.n_classes,
            "image_size": self.image_size,
            "context": self.context,
            "hidden": self.hidden,
            "use_depth": self.use_depth,
            "anchored": self.anchored,
            "track_horizon": self.track_horizon,
            "settle_frames": self.settle_frames,
        }


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


def block_displacements(before: torch.Tensor, after: torch.Tensor, n_classes: int) -> tuple[torch.Tensor, torch.Tensor]:
    """Each block's centroid displacement (B, K, 2) in pixels (x, y) between true labels (B, S, S) of two
    consecutive frames -- what the model's displacement should be -- and each block's area in ``after``
    (B, K), zero where the block is missing from either frame (no displacement defined).  K = ``n_classes`` - 1,
    given rather than read off the labels: a batch need not show every block (a structure of few pieces)."""
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


def predict_batch(
    model: FallPredictor, windows: np.ndarray, horizon: int, depth: np.ndarray | None = None, batch_size: int = 64
) -> np.ndarray:
    """Predicted labels (B, horizon, S, S) after context windows (B, K, S, S) of labels (and of depth images,
    for a ``use_depth`` model), ``batch_size`` windows at a time (a rollout's activations grow with the batch)."""
    predicted = np.zeros((len(windows), horizon, *windows.shape[-2:]), dtype=np.uint8)
    with torch.no_grad():
        for b in range(0, len(windows), batch_size):
            inputs = model_inputs(
                model, windows[b : b + batch_size], None if depth is None else depth[b : b + batch_size]
            )
            predicted[b : b + batch_size] = model.rollout(inputs, horizon).argmax(2).numpy()
    return predicted


def load_fall_model(path: Path | str) -> tuple[FallPredictor, dict[str, Any]]:
    """A trained model and its saved facts (classes, image size, context) from a ``.pt`` checkpoint."""
    path = Path(path)
    if not path.is_file():
        raise ValueError(f"fall-dynamics checkpoint {path} not found")
    try:
        saved = torch.load(path, map_location="cpu", weights_only=True)  # tensors and plain data: nothing runs
    except Exception as error:
        raise ValueError(f"cannot load fall-dynamics checkpoint {path}: {error}") from error
    if saved.get("architecture") != ARCHITECTURE:
        raise ValueError(
            f"fall-dynamics checkpoint {path} is of model architecture {saved.get('architecture', 1)}; "
            f"this code runs architecture {ARCHITECTURE}: retrain it with train.py"
        )
    try:
        model = FallPredictor(**saved["model_args"])
        model.load_state_dict(saved["model"])
    except Exception as error:
        raise ValueError(f"cannot load fall-dynamics checkpoint {path}: {error}") from error
    return model, saved
