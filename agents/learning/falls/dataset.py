"""Falling-tower datasets read for training: a checked loader of the shards the recorder writes, by split.

The format (``panda_grasp_env/falls/shards.py``): a folder of ``shard_NNNNN.npz`` files and ``metadata.json``,
which lists every shard with its sequence count, byte size and SHA-256; the loader checks them, so a corrupt
or truncated shard is reported by name.  Splits are by sequence: seed % 10 in 0-7 train, 8 validation, 9 test.
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from panda_grasp_env.falls.shards import LABEL_SOURCES, LEGACY_TOWER_BLOCKS, SPLITS, read_metadata, split_of
from panda_grasp_env.tooling.runs import sha256


@dataclass
class FallSequences:
    """Sequences of one split, in memory: ``labels`` (N, T, S, S) uint8 class ids, ``poses`` (N, T, B, 7)
    float32 block positions (m) and quaternions in the world frame (NaN rows past a sequence's own blocks),
    ``n_blocks`` (N,) each tower's height in blocks, ``crop_origin`` (N, 2) the (column, row) of each crop's
    corner in the rendered image, ``camera`` the overhead camera of ``metadata.json`` (``render_size``, ``K``,
    ``rotation`` camera -> world in OpenCV axes, ``position`` m) and, if loaded, ``depth`` (N, T, S, S) float16
    metres along the camera's optical axis, and for structure datasets recorded since the field existed
    ``candidate_kind`` (N,) each candidate's kind (``structure_falls.CANDIDATE_KINDS``)."""

    labels: np.ndarray
    seeds: np.ndarray
    classes: list[str]
    frame_interval: float
    poses: np.ndarray
    n_blocks: np.ndarray
    crop_origin: np.ndarray
    camera: dict[str, Any]
    depth: np.ndarray | None = None
    candidate_kind: np.ndarray | None = None

    @property
    def image_size(self) -> int:
        return int(self.labels.shape[-1])


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
    kept: dict[str, list[np.ndarray]] = {
        name: [] for name in [*names, "seeds", "poses", "crop_origin", "n_blocks", "candidate_kind"]
    }
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
                if "candidate_kind" in shard.files:
                    arrays["candidate_kind"] = shard["candidate_kind"]
        except (OSError, ValueError, KeyError) as error:
            raise ValueError(f"shard {entry['file']} cannot be read: {error}") from error
        n, frames, crop = entry["sequences"], meta["frames"], meta["crop"]
        shapes = {name: (n, frames, crop, crop) for name in names} | {
            "poses": (n, frames, len(meta["classes"]) - 1, 7),
            "crop_origin": (n, 2),
            "seeds": (n,),
            "n_blocks": (n,),
            "candidate_kind": (n,),
        }
        wrong = [
            f"{name} of shape {arrays[name].shape}, expected {shape}"
            for name, shape in shapes.items()
            if name in arrays and arrays[name].shape != shape
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
        # Only if every shard has it (a dataset resumed across the change would not).
        np.concatenate(kept["candidate_kind"]) if len(kept["candidate_kind"]) == len(meta["shards"]) else None,
    )
