"""How much does the tall-tower fall model's track head gain from data?  Its t+5 block IoU by training set size.

    python benchmarks/fall_data_scaling.py [--dataset data/falls_tall_12800] [--sizes 320,640,1280,2560,5120,10240]
                                           [--epochs 60] [--horizon 5]
                                           [--out results/benchmarks/fall_data_scaling.json]

The fall model with a track head (``configs/fall_convlstm_tall.yaml``) plans each block's displacement to every
next frame from the blocks' tracks over the context frames (``agents/learning/falls/tracks.py``), and its
training fits that head alone before the ConvLSTM's epochs (``training.pretrain_track_head``).  Here the head
is fitted the same way on the first N training sequences, for each N of ``--sizes``, and each block's mask at
frame t moved by its planned displacement to t + horizon (``baselines.translate_blocks``) is scored on the
validation split (seed % 10 = 8) by mean block IoU over the windows ``metrics.evaluate`` scores, beside
copying frame t and the translation oracle (the true displacements).  The ConvLSTM's share (what it adds to
the plan and its correction logits) is not in these figures.  No test sequence is read.  Seeded (torch seed
0 before each fit): the same dataset gives the same figures.
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

import numpy as np
import torch

from panda_grasp_env.agents.learning.falls.baselines import translate_blocks
from panda_grasp_env.agents.learning.falls.dataset import FallSequences, load_split
from panda_grasp_env.agents.learning.falls.metrics import Confusion
from panda_grasp_env.agents.learning.falls.model import FallPredictor
from panda_grasp_env.agents.learning.falls.training import fit_track_head, track_windows
from panda_grasp_env.tooling.runs import write_json

CONTEXT = 4


def block_iou(split: FallSequences, where: np.ndarray, moves: np.ndarray, horizon: int) -> float:
    """Mean block IoU at t + horizon of each (sequence, t)'s frame-t masks moved by ``moves`` (N, 2: x, y
    pixels) of the blocks ``where`` (N, 3: sequence, t, block class - 1)."""
    by_frame: dict[tuple[int, int], dict[int, np.ndarray]] = {}
    for (i, t, k), (x, y) in zip(where.tolist(), moves):
        by_frame.setdefault((i, t), {})[k + 1] = np.array([y, x])  # translate_blocks takes rows, columns
    confusion = Confusion(len(split.classes))
    for (i, t), displacement in by_frame.items():
        confusion.add(split.labels[i, t + horizon], translate_blocks(split.labels[i, t], displacement))
    return confusion.summary(split.classes)["mean_block_iou"]


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--dataset", default="data/falls_tall_12800")
    parser.add_argument("--sizes", default="320,640,1280,2560,5120,10240", help="training sequences, comma-separated")
    parser.add_argument("--epochs", type=int, default=60)
    parser.add_argument("--horizon", type=int, default=5)
    parser.add_argument("--out", default="results/benchmarks/fall_data_scaling.json")
    args = parser.parse_args()
    sizes = [int(n) for n in args.sizes.split(",")]
    torch.set_num_threads(1)
    train = load_split(args.dataset, "train", depth=True)
    val = load_split(args.dataset, "val", verify=False, depth=True)
    if max(sizes) > len(train.labels) or min(sizes) < 1:
        raise ValueError(f"--sizes must lie in 1-{len(train.labels)} (the training sequences), got {sizes}")
    length = train.labels.shape[1]
    if not 1 <= args.horizon <= length - CONTEXT:
        raise ValueError(f"--horizon must lie in 1-{length - CONTEXT} for sequences of {length} frames")

    def head_model() -> FallPredictor:
        torch.manual_seed(0)
        classes = len(train.classes)
        return FallPredictor(
            classes, train.image_size, CONTEXT, use_depth=True, anchored=True, track_horizon=length - CONTEXT
        )

    rows = track_windows(head_model(), train, length - CONTEXT)
    val_rows = track_windows(head_model(), val, length - CONTEXT)
    scored = (val_rows[3][:, 1] < length - args.horizon).numpy()  # the windows metrics.evaluate scores
    where = val_rows[3].numpy()[scored]
    seen_later = val_rows[2][:, args.horizon - 1].numpy()[scored, None]
    truth = val_rows[1][:, args.horizon - 1].numpy()[scored] * seen_later  # zero for a block gone from view
    results = {
        "copy last frame": block_iou(val, where, np.zeros_like(truth), args.horizon),
        "translation oracle": block_iou(val, where, truth, args.horizon),
    }
    for n in sizes:
        model = head_model()
        first = (rows[3][:, 0] < n).nonzero()[:, 0]
        fit_track_head(model.tracks, tuple(part[first] for part in rows), val_rows, args.epochs)
        with torch.no_grad():
            moves = model.tracks(val_rows[0][scored][:, None])[:, 0, args.horizon - 1].numpy()
        results[f"track head, {n} training sequences"] = block_iou(val, where, moves, args.horizon)
        print(f"{n} training sequences: {results[f'track head, {n} training sequences']:.4f}", flush=True)
    print(f"| predictor ({args.dataset}, validation: {len(val.labels)} sequences) | t+{args.horizon} mean block IoU |")
    print("|---|---|")
    for name, iou in results.items():
        print(f"| {name} | {iou:.4f} |")
    Path(args.out).parent.mkdir(parents=True, exist_ok=True)
    write_json(Path(args.out), {"dataset": args.dataset, "horizon": args.horizon, "mean_block_iou": results})


if __name__ == "__main__":
    main()
