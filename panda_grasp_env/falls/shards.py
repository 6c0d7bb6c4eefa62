"""Falling-tower datasets: the shard format the recorder writes (``recorder.py``), and its ``metadata.json``.

A dataset is a folder of ``shard_NNNNN.npz`` files (NumPy, zip-compressed) and
``metadata.json``.  Each shard holds ``sequences`` sequences of ``frames``
top-view frames cropped around the tower:

==================  ==========================  =========================================================
array               shape, dtype                meaning
==================  ==========================  =========================================================
``rgb``             (N, T, S, S, 3) uint8       overhead camera colour
``depth``           (N, T, S, S) float16        depth along the optical axis, metres
``labels``          (N, T, S, S) uint8          true segmentation: 0 background (table, robot), 1 + block
``colour_labels``   (N, T, S, S) uint8          the same classes from ``panda_grasp_env.perception.segmentation.colour_masks``
``poses``           (N, T, B, 7) float32        block position (m) and quaternion (w, x, y, z), world frame;
                                                B: the tallest tower's blocks, NaN rows past a lower one's
``n_blocks``        (N,) uint8                  the sequence's tower height in blocks (absent before
                                                heights were a setting: all 4)
``seeds``           (N,) int64                  env reset seed of each sequence
``breaker``         (N,) uint8                  0 impulse, 1 push
``strike``          (N, 5) float32              level struck, heading (rad), impulse (N s, 0 for push), x, y (m)
``crop_origin``     (N, 2) int32                (column, row) of the crop's corner in the rendered image
``candidate_kind``  (N,) uint8                  structure scenes only (recorded since 2026-12-07): the
                                                candidate's kind, an index into
                                                ``structure_falls.CANDIDATE_KINDS``
==================  ==========================  =========================================================

NumPy shards need no extra dependency, load with memory to spare at this size
(a 2,000-sequence set is a few hundred MB), and make resuming and parallel
writing trivial: one worker writes one shard, atomically.  ``metadata.json``
lists every shard with its sequence count, byte size and SHA-256, which the
loader (``panda_grasp_env.agents.learning.falls.dataset``) checks, so a corrupt or truncated shard is
reported by name.

Splits are by sequence: seed % 10 in 0-7 train, 8 validation, 9 test.
"""

from __future__ import annotations

from pathlib import Path
from typing import Any

from panda_grasp_env.tooling.reading import MAX_DOCUMENT_BYTES, read_json

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
#: Arrays only the structure scene records.
STRUCTURE_ARRAYS = ("candidate_kind",)
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


def read_metadata(root: Path | str) -> dict[str, Any]:
    root = Path(root)
    path = root / "metadata.json"
    if not path.is_file():
        raise ValueError(
            f"{root} is not a fall dataset: metadata.json missing (record one with python -m panda_grasp_env.falls)"
        )
    return read_json(path, MAX_DOCUMENT_BYTES)
