"""Block tracks: where each block's pixels lie in each frame, and what a fall model's track head reads of them.

A tall tower's blocks come into view and cover one another as it falls, so a block's next positions are read
from its own short track (its centroid steps, visible area and mean height over the context frames) and from
the others' (where each lies against it, how it moves, how high it is): a block at the top of a toppling
tower moves furthest.  ``track_features`` builds that per block; ``TrackHead`` maps it to the block's
displacement to each of the next frames.  Pixels throughout: x = column, y = row of the frame.
"""

from __future__ import annotations

import torch
from torch import nn

#: Pixels of a block's mask below which it counts as out of view.
SEEN_AREA = 0.5
#: Per-block state each block reads of every block (``track_features``): position against this block and
#: against the tower's mean (tens of pixels), centroid step (pixels), visible area (hundreds of pixels), mean
#: height (blocks) and whether it is in view.
NEIGHBOUR_FEATURES = 7


def mask_centroids(masks: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
    """Centroids (B, K, 2) in pixels (x = column, y = row) and masses (B, K) of masks (B, K, S, S), hard or
    soft; a centroid is zero where its mask is empty."""
    mass = masks.sum((2, 3))
    pixels = torch.arange(masks.shape[-1], dtype=masks.dtype, device=masks.device)
    x = (masks.sum(2) * pixels).sum(2) / mass.clamp_min(1e-6)
    y = (masks.sum(3) * pixels).sum(2) / mass.clamp_min(1e-6)
    return torch.stack([x, y], 2), mass


def block_tracks(frames: torch.Tensor, n_classes: int) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor]:
    """Centroids (B, T, K, 2; pixels), visible areas (B, T, K; pixels) and mean heights (B, T, K; blocks, zero
    without a height map) of the K = ``n_classes`` - 1 blocks in frames (B, T, C [+ 1], S, S): class maps and,
    after them, an optional height map (``model.model_inputs``)."""
    batch, length = frames.shape[:2]
    flat = frames.flatten(0, 1)
    masks = flat[:, 1:n_classes]
    centre, area = mask_centroids(masks)
    if flat.shape[1] > n_classes:
        height = (masks * flat[:, n_classes:]).sum((2, 3)) / area.clamp_min(1e-6)
    else:
        height = torch.zeros_like(area)
    return centre.view(batch, length, -1, 2), area.view(batch, length, -1), height.view(batch, length, -1)


def track_features(centre: torch.Tensor, area: torch.Tensor, height: torch.Tensor, image_size: int) -> torch.Tensor:
    """(B, K, F) features of each block at the newest of T frames, from tracks (``block_tracks``) over those
    frames: its centroid displacement from each earlier frame and whether it was in view there, its visible
    area and mean height in each frame, its position against the tower's mean and the crop's middle, the
    tower's mean step, then every block's ``NEIGHBOUR_FEATURES`` in order of in-view-ness and height (the
    highest first).  F = 3 (T - 1) + 2 T + 6 + 7 K."""
    length = centre.shape[1]
    seen = (area > SEEN_AREA).float()  # (B, T, K)
    now, seen_now = centre[:, -1], seen[:, -1, :, None]
    history = []
    for back in range(1, length):
        known = seen[:, -1 - back, :, None] * seen_now
        history += [(now - centre[:, -1 - back]) * known, known]
    tower = (now * seen_now).sum(1, keepdim=True) / seen_now.sum(1, keepdim=True).clamp_min(1)
    moving = seen_now * seen[:, -2, :, None] if length > 1 else torch.zeros_like(seen_now)
    step = (now - centre[:, -2]) * moving if length > 1 else torch.zeros_like(now)
    tower_step = step.sum(1, keepdim=True) / moving.sum(1, keepdim=True).clamp_min(1)
    against_tower = (now - tower) / 10 * seen_now
    own = [
        *history,
        area.transpose(1, 2) / 100,
        height.transpose(1, 2),
        against_tower,
        (now - image_size / 2) / 10 * seen_now,
        tower_step.expand_as(now),
    ]
    state = torch.cat([against_tower, step, area[:, -1, :, None] / 100, height[:, -1, :, None], seen_now], 2)
    order = torch.argsort(seen[:, -1] * 100 + height[:, -1], dim=1, descending=True, stable=True)
    ordered = torch.gather(state, 1, order[..., None].expand_as(state))  # (B, K, 7), the same for every block
    neighbours = ordered[:, None].repeat(1, state.shape[1], 1, 1)  # (B, K, K, 7)
    neighbours[..., :2] -= against_tower[:, :, None] * ordered[:, None, :, 6:7]
    return torch.cat([*own, neighbours.flatten(2)], 2)


def track_feature_count(context: int, blocks: int) -> int:
    """F of ``track_features`` for ``context`` frames of ``blocks`` blocks."""
    return 3 * (context - 1) + 2 * context + 6 + NEIGHBOUR_FEATURES * blocks


class TrackHead(nn.Module):
    """Each block's displacement (pixels, x then y) from the newest context frame to each of the next
    ``horizon`` frames, from its standardised ``track_features`` (``mean`` and ``scale`` are set by
    ``training.pretrain_track_head`` and saved with the weights)."""

    def __init__(self, features: int, horizon: int, width: int = 256) -> None:
        super().__init__()
        self.horizon = horizon
        self.register_buffer("mean", torch.zeros(features))
        self.register_buffer("scale", torch.ones(features))
        self.network = nn.Sequential(
            nn.Linear(features, width), nn.ReLU(), nn.Linear(width, width), nn.ReLU(), nn.Linear(width, 2 * horizon)
        )
        nn.init.zeros_(self.network[-1].weight)  # untrained: every block stays where it is (copy the last frame)
        nn.init.zeros_(self.network[-1].bias)

    def forward(self, features: torch.Tensor) -> torch.Tensor:
        """(B, K, horizon, 2) displacements from (B, K, F) features."""
        moved = self.network((features - self.mean) / self.scale)
        return moved.view(*features.shape[:2], self.horizon, 2)
