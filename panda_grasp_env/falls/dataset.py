"""Falling-tower datasets: the shard format the recorder writes and a checked loader.

A dataset is a folder of ``shard_NNNNN.npz`` files (NumPy, zip-compressed) and
``metadata.json``.  Each shard holds ``sequences`` sequences of ``frames``
top-view frames cropped around the tower:

=================  ==========================  =========================================================
array              shape, dtype                meaning
=================  ==========================  =========================================================
``rgb``            (N, T, S, S, 3) uint8       overhead camera colour
``depth``          (N, T, S, S) float16        depth along the optical axis, metres
``labels``         (N, T, S, S) uint8          true segmentation: 0 background (table, robot), 1 + block
``colour_labels``  (N, T, S, S) uint8          the same classes from ``panda_grasp_env.perception.segmentation.colour_masks``
``poses``          (N, T, B, 7) float32        block position (m) and quaternion (w, x, y, z), world frame
``seeds``          (N,) int64                  env reset seed of each sequence
``breaker``        (N,) uint8                  0 impulse, 1 push
``strike``         (N, 5) float32              level struck, heading (rad), impulse (N s, 0 for push), x, y (m)
``crop_origin``    (N, 2) int32                (column, row) of the crop's corner in the rendered image
=================  ==========================  =========================================================

NumPy shards need no extra dependency, load with memory to spare at this size
(a 2,000-sequence set is a few hundred MB), and make resuming and parallel
writing trivial: one worker writes one shard, atomically.  ``metadata.json``
lists every shard with its sequence count, byte size and SHA-256, which the
loader checks, so a corrupt or truncated shard is reported by name.

Splits are by sequence: seed % 10 in 0-7 train, 8 validation, 9 test.
"""

from __future__ import annotations

import json
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from panda_grasp_env.tooling.runs import sha256

SHARD_ARRAYS = ("rgb", "depth", "labels", "colour_labels", "poses", "seeds", "breaker", "strike", "crop_origin")
SPLITS = ("train", "val", "test")


def split_of(seed: int) -> str:
    """The split a sequence belongs to, from its seed."""
    return "train" if seed % 10 < 8 else "val" if seed % 10 == 8 else "test"


@dataclass
class FallSequences:
    """Segmentation sequences of one split, in memory: ``labels`` (N, T, S, S) uint8 class ids and, if loaded,
    ``depth`` (N, T, S, S) float16 metres along the camera's optical axis."""

    labels: np.ndarray
    seeds: np.ndarray
    classes: list[str]
    frame_interval: float
    depth: np.ndarray | None = None

    @property
    def image_size(self) -> int:
        return int(self.labels.shape[-1])


def read_metadata(root: Path | str) -> dict[str, Any]:
    root = Path(root)
    path = root / "metadata.json"
    if not path.is_file():
        raise ValueError(
            f"{root} is not a fall dataset: metadata.json missing (record one with python -m panda_grasp_env.falls)"
        )
    return json.loads(path.read_text())


def verify_shard(root: Path, entry: dict[str, Any]) -> None:
    """``ValueError`` naming the shard if it is missing, truncated, altered or has the wrong length."""
    path = root / entry["file"]
    if not path.is_file():
        raise ValueError(f"shard {entry['file']} listed in metadata.json is missing from {root}")
    size = path.stat().st_size
    if size != entry["bytes"]:
        raise ValueError(f"shard {entry['file']} is truncated or altered: {size} bytes, metadata says {entry['bytes']}")
    if sha256(path) != entry["sha256"]:
        raise ValueError(f"shard {entry['file']} is corrupt: its SHA-256 does not match metadata.json")


def load_split(
    root: Path | str, split: str, label_source: str = "labels", verify: bool = True, depth: bool = False
) -> FallSequences:
    """All sequences of ``split`` (``train``, ``val``, ``test``); ``label_source``: ``labels`` or
    ``colour_labels``; with ``depth`` also their depth images."""
    if split not in SPLITS:
        raise ValueError(f"unknown split {split!r}; valid: {list(SPLITS)}")
    if label_source not in ("labels", "colour_labels"):
        raise ValueError(f"label_source must be 'labels' or 'colour_labels', got {label_source!r}")
    root = Path(root)
    meta = read_metadata(root)
    names = [label_source, "depth"] if depth else [label_source]
    kept: dict[str, list[np.ndarray]] = {name: [] for name in [*names, "seeds"]}
    for entry in meta["shards"]:
        if verify:
            verify_shard(root, entry)
        try:
            with np.load(root / entry["file"]) as shard:
                arrays = {name: shard[name] for name in [*names, "seeds"]}
        except (OSError, ValueError, KeyError) as error:
            raise ValueError(f"shard {entry['file']} cannot be read: {error}") from error
        expected = (entry["sequences"], meta["frames"], meta["crop"], meta["crop"])
        wrong = {name: arrays[name].shape for name in names if arrays[name].shape != expected}
        if wrong or arrays["seeds"].shape != (entry["sequences"],):
            shapes = ", ".join(f"{name} of shape {shape}" for name, shape in wrong.items()) or "a wrong seed count"
            raise ValueError(f"shard {entry['file']} has {shapes}, expected {expected}")
        keep = np.array([split_of(int(s)) == split for s in arrays["seeds"]], dtype=bool)
        for name, array in arrays.items():
            kept[name].append(array[keep])
    if not meta["shards"]:
        raise ValueError(f"{root} lists no shards")
    return FallSequences(
        np.concatenate(kept[label_source]),
        np.concatenate(kept["seeds"]),
        list(meta["classes"]),
        float(meta["frame_interval"]),
        np.concatenate(kept["depth"]) if depth else None,
    )
