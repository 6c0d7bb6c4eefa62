"""Is the tall-tower fall model short of data?  A probe: per-block displacement five frames on, by training set size.

    python benchmarks/fall_data_scaling.py [--dataset data/falls_tall_3200] [--sizes 320,640,1280,2560]
                                           [--horizon 5] [--out results/benchmarks/fall_data_scaling.json]

For every block seen at frame t of a training sequence (t with 4 frames of context and t + horizon inside the
sequence), a small network (two hidden layers of 256) reads the block's centroid history (its steps from the
3 frames before, pixels), its visible area and mean height (blocks, from the depth image) in the 4 frames, where
it lies against the tower's mean and the crop's middle, the tower's mean step and t, and predicts the block's
centroid displacement to t + horizon (pixels).  Each block's mask at t moved by that displacement is the
prediction (``baselines.translate_blocks``), scored on the validation split (seed % 10 = 8) by mean block IoU
as ``metrics`` scores the model, beside copying frame t and the translation oracle (the true displacements).
The network is trained on the first N training sequences, for each N of ``--sizes``: the fall model's motion
network reads the same kind of history, so how the probe grows with N says how much more data would give.
No test sequence is read.  Seeded (torch seed 0): the same dataset gives the same figures.
"""

from __future__ import annotations

import argparse
import sys
from collections.abc import Callable
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

import numpy as np
import torch

from panda_grasp_env.falls.baselines import translate_blocks
from panda_grasp_env.falls.dataset import FallSequences, load_split
from panda_grasp_env.falls.metrics import Confusion
from panda_grasp_env.falls.model import heights, mask_centroids, one_hot
from panda_grasp_env.tooling.runs import write_json

CONTEXT = 4


def block_tracks(split: FallSequences, index: int) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Centroids (T, K, 2: row, column, NaN where unseen), visible areas (T, K, pixels) and mean heights (T, K,
    blocks) of sequence ``index``'s blocks (``model.mask_centroids`` of their masks)."""
    masks = one_hot(torch.as_tensor(split.labels[index]), len(split.classes))[:, 1:].double()
    centre, area = mask_centroids(masks)
    height = (masks * heights(torch.as_tensor(split.depth[index])).double()).sum((2, 3)) / area.clamp_min(1)
    seen = (area > 0).numpy()
    return np.where(seen[..., None], centre.numpy()[..., ::-1], np.nan), area.numpy(), height.numpy()


def samples(split: FallSequences, horizon: int) -> tuple[np.ndarray, np.ndarray, list[tuple[int, int, int]]]:
    """Features (N, F), targets (N, 3: displacement row, column in pixels; 1 if the block is seen at t + horizon)
    and (sequence, t, block) of every block seen at t."""
    features, targets, where = [], [], []
    size = split.image_size
    for i in range(len(split.labels)):
        centre, area, mean_height = block_tracks(split, i)
        for t in range(CONTEXT - 1, centre.shape[0] - horizon):
            seen = area[t] > 0
            if not seen.any():
                continue
            tower = centre[t][seen].mean(0)
            both = seen & (area[t - 1] > 0)
            tower_step = (centre[t] - centre[t - 1])[both].mean(0) if both.any() else np.zeros(2)
            for k in np.flatnonzero(seen):
                history = []
                for back in range(1, CONTEXT):
                    known = area[t - back, k] > 0
                    history += [*(centre[t, k] - centre[t - back, k] if known else np.zeros(2)), float(known)]
                window = slice(t - CONTEXT + 1, t + 1)
                features.append(
                    [
                        *history,
                        *(area[window, k] / 100),
                        *mean_height[window, k],
                        *(centre[t, k] - tower) / 10,
                        *(centre[t, k] - size / 2) / 10,
                        *tower_step,
                        t / centre.shape[0],
                    ]
                )
                later = area[t + horizon, k] > 0
                targets.append([*(centre[t + horizon, k] - centre[t, k] if later else np.zeros(2)), float(later)])
                where.append((i, t, k))
    return np.asarray(features, np.float32), np.asarray(targets, np.float32), where


def fit(features: np.ndarray, targets: np.ndarray, epochs: int = 60) -> Callable[[np.ndarray], np.ndarray]:
    """A two-layer network from standardised features to displacements (smooth L1, blocks seen at the end), as
    a function of raw features."""
    torch.manual_seed(0)
    mean, scale = features.mean(0), features.std(0) + 1e-6
    network = torch.nn.Sequential(
        torch.nn.Linear(features.shape[1], 256),
        torch.nn.ReLU(),
        torch.nn.Linear(256, 256),
        torch.nn.ReLU(),
        torch.nn.Linear(256, 2),
    )
    optimiser = torch.optim.Adam(network.parameters(), 1e-3)
    x, y, seen = (
        torch.as_tensor((features - mean) / scale),
        torch.as_tensor(targets[:, :2]),
        torch.as_tensor(targets[:, 2]),
    )
    for _ in range(epochs):
        order = torch.randperm(len(x))
        for start in range(0, len(x), 256):
            batch = order[start : start + 256]
            error = torch.nn.functional.smooth_l1_loss(network(x[batch]), y[batch], reduction="none").sum(1)
            loss = (error * seen[batch]).sum() / seen[batch].sum().clamp_min(1)
            optimiser.zero_grad()
            loss.backward()
            optimiser.step()
    network.eval()

    def predict(raw: np.ndarray) -> np.ndarray:
        with torch.no_grad():
            return network(torch.as_tensor((raw - mean) / scale)).numpy()

    return predict


def block_iou(split: FallSequences, where: list, moves: np.ndarray, horizon: int) -> float:
    """Mean block IoU at t + horizon of each (sequence, t)'s frame-t masks moved by ``moves`` (N, 2)."""
    by_frame: dict[tuple[int, int], dict[int, np.ndarray]] = {}
    for (i, t, k), move in zip(where, moves):
        by_frame.setdefault((i, t), {})[k + 1] = move
    confusion = Confusion(len(split.classes))
    for (i, t), displacement in by_frame.items():
        confusion.add(split.labels[i, t + horizon], translate_blocks(split.labels[i, t], displacement))
    return confusion.summary(split.classes)["mean_block_iou"]


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--dataset", default="data/falls_tall_3200")
    parser.add_argument("--sizes", default="320,640,1280,2560", help="training sequences, comma-separated")
    parser.add_argument("--horizon", type=int, default=5)
    parser.add_argument("--out", default="results/benchmarks/fall_data_scaling.json")
    args = parser.parse_args()
    sizes = [int(n) for n in args.sizes.split(",")]
    torch.set_num_threads(1)
    train = load_split(args.dataset, "train", depth=True)
    val = load_split(args.dataset, "val", verify=False, depth=True)
    if max(sizes) > len(train.labels) or min(sizes) < 1:
        raise ValueError(f"--sizes must lie in 1-{len(train.labels)} (the training sequences), got {sizes}")
    x_val, y_val, where = samples(val, args.horizon)
    rows = {
        "copy last frame": block_iou(val, where, np.zeros_like(y_val[:, :2]), args.horizon),
        "translation oracle": block_iou(val, where, y_val[:, :2], args.horizon),
    }
    x_train, y_train, train_where = samples(train, args.horizon)
    sequence = np.array([i for i, _, _ in train_where])
    for n in sizes:
        moves = fit(x_train[sequence < n], y_train[sequence < n])(x_val)
        rows[f"probe, {n} training sequences"] = block_iou(val, where, moves, args.horizon)
    print(f"| predictor ({args.dataset}, validation: {len(val.labels)} sequences) | t+{args.horizon} mean block IoU |")
    print("|---|---|")
    for name, iou in rows.items():
        print(f"| {name} | {iou:.4f} |")
    Path(args.out).parent.mkdir(parents=True, exist_ok=True)
    write_json(Path(args.out), {"dataset": args.dataset, "horizon": args.horizon, "mean_block_iou": rows})


if __name__ == "__main__":
    main()
