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
``poses``          (N, T, B, 7) float32        block position (m) and quaternion (w, x, y, z), world frame;
                                               B: the tallest tower's blocks, NaN rows past a lower one's
``n_blocks``       (N,) uint8                  the sequence's tower height in blocks (absent before
                                               heights were a setting: all 4)
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

from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from panda_grasp_env.tooling.reading import MAX_DOCUMENT_BYTES, read_json
from panda_grasp_env.tooling.runs import sha256

SHARD_ARRAYS = (
    "rgb",
    "depth",
    "labels",
    "colour_labels",
    "poses",
    "n_blocks",
    "seeds",
    "breaker",
    "strike",
    "crop_origin",
)
SPLITS = ("train", "val", "test")
#: The class maps a model may learn from: the simulator's segmentation, or perception's colour segmentation.
LABEL_SOURCES = ("labels", "colour_labels")
#: The tower height (blocks) of every sequence recorded before heights were a setting (no ``n_blocks`` array).
LEGACY_TOWER_BLOCKS = 4


def split_of(seed: int) -> str:
    """The split a sequence belongs to, from its seed."""
    return "train" if seed % 10 < 8 else "val" if seed % 10 == 8 else "test"


def tower_heights(meta: dict[str, Any]) -> list[int]:
    """The tower heights (blocks) a dataset's recorder drew from, from its ``metadata.json``."""
    return sorted(meta.get("tower_blocks", [LEGACY_TOWER_BLOCKS]))


@dataclass
class FallSequences:
    """Sequences of one split, in memory: ``labels`` (N, T, S, S) uint8 class ids, ``poses`` (N, T, B, 7)
    float32 block positions (m) and quaternions in the world frame (NaN rows past a sequence's own blocks),
    ``n_blocks`` (N,) each tower's height in blocks, ``crop_origin`` (N, 2) the (column, row) of each crop's
    corner in the rendered image, ``camera`` the overhead camera of ``metadata.json`` (``render_size``, ``K``,
    ``rotation`` camera -> world in OpenCV axes, ``position`` m) and, if loaded, ``depth`` (N, T, S, S) float16
    metres along the camera's optical axis."""

    labels: np.ndarray
    seeds: np.ndarray
    classes: list[str]
    frame_interval: float
    poses: np.ndarray
    n_blocks: np.ndarray
    crop_origin: np.ndarray
    camera: dict[str, Any]
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
    return read_json(path, MAX_DOCUMENT_BYTES)


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
    if label_source not in LABEL_SOURCES:
        raise ValueError(f"label_source must be one of {list(LABEL_SOURCES)}, got {label_source!r}")
    root = Path(root)
    meta = read_metadata(root)
    names = [label_source, "depth"] if depth else [label_source]
    kept: dict[str, list[np.ndarray]] = {name: [] for name in [*names, "seeds", "poses", "crop_origin", "n_blocks"]}
    for entry in meta["shards"]:
        if verify:
            verify_shard(root, entry)
        try:
            with np.load(root / entry["file"]) as shard:
                arrays = {name: shard[name] for name in [*names, "seeds", "poses", "crop_origin"]}
                arrays["n_blocks"] = (
                    shard["n_blocks"]
                    if "n_blocks" in shard.files
                    else np.full(entry["sequences"], LEGACY_TOWER_BLOCKS, dtype=np.uint8)
                )
        except (OSError, ValueError, KeyError) as error:
            raise ValueError(f"shard {entry['file']} cannot be read: {error}") from error
        n, frames, crop = entry["sequences"], meta["frames"], meta["crop"]
        shapes = {name: (n, frames, crop, crop) for name in names} | {
            "poses": (n, frames, len(meta["classes"]) - 1, 7),
            "crop_origin": (n, 2),
            "seeds": (n,),
            "n_blocks": (n,),
        }
        wrong = [
            f"{name} of shape {arrays[name].shape}, expected {shape}"
            for name, shape in shapes.items()
            if arrays[name].shape != shape
        ]
        if wrong:
            raise ValueError(f"shard {entry['file']} has {'; '.join(wrong)}")
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
        np.concatenate(kept["poses"]),
        np.concatenate(kept["n_blocks"]).astype(np.int64),
        np.concatenate(kept["crop_origin"]),
        dict(meta["camera"]),
        np.concatenate(kept["depth"]) if depth else None,
    )
