"""Record falling-tower sequences from the env:  python -m panda_grasp_env.falls --out data/falls --sequences 2000

(``--scene structures`` records pieces set down on partly built structures instead: ``structure_falls.py``.)

Each sequence: ``PandaTowerBreak-v0`` resets with its seed (a tower of one of
``tower_blocks`` heights -- 4 blocks by default, drawn per sequence -- in random
colour order, position and yaw), one ``env.step`` breaks it -- a random
horizontal impulse on a block at a random level of ``strike_levels`` (the
source study's protocol) or a push -- and, from the moment a block starts to
move (and is ``start_shift`` from its place), the overhead camera is
sampled every ``frame_interval`` seconds of simulated time: RGB, depth, the
simulator's segmentation and ``perception``'s colour segmentation, cropped to
a square around the tower, plus every block's pose.  The settings (``RecorderSettings``) are in
``panda_grasp_env/falls/settings.py``, the format in ``panda_grasp_env/falls/shards.py``.

Shards are written atomically by parallel workers; a rerun with the same
arguments keeps the finished shards (checked by size and SHA-256) and records
only the rest.  The recorder prints the sequences per second it achieved.
"""

from __future__ import annotations

import argparse
import json
import multiprocessing
import platform
import sys
import time
from dataclasses import asdict, replace
from pathlib import Path
from typing import Any

import numpy as np

from panda_grasp_env.falls.settings import BREAKERS, LATER_SETTINGS, RENDER_SIZE, RecorderSettings
from panda_grasp_env.falls.shards import SHARD_ARRAYS, STRUCTURE_ARRAYS, split_of
from panda_grasp_env.falls.structure_falls import StructureRecorder
from panda_grasp_env.model.structure_generator import MAX_PIECES
from panda_grasp_env.sim.stepping import body_speeds
from panda_grasp_env.tooling.reading import MAX_DOCUMENT_BYTES, read_json
from panda_grasp_env.tooling.runs import (
    atomic_path,
    checked_config,
    interrupt_on_signals,
    sha256,
    write_atomically,
)

#: Block speed (m/s) above which the fall has begun (once a block is also ``start_shift`` from the tower).
MOTION_SPEED = 0.01


class FrameGrabber:
    """A workcell step observer: once the blocks move (a block faster than ``MOTION_SPEED`` and one at least
    ``start_shift`` from its place in ``tower``, (B, 3) world positions in metres), grab a cropped frame every
    ``frame_interval`` seconds."""

    def __init__(
        self, env: Any, settings: RecorderSettings, origin: tuple[int, int], colours: dict, tower: np.ndarray
    ) -> None:
        self.env, self.settings, self.origin, self.colours = env, settings, origin, colours
        self.tower = tower
        self.start: float | None = None
        self.frames: list[dict[str, np.ndarray]] = []

    @property
    def done(self) -> bool:
        return len(self.frames) >= self.settings.frames

    def on_control_step(self, cell: Any) -> None:
        if self.done:
            return
        if self.start is None:
            moving = np.any(body_speeds(cell.data, cell.block_ids) >= MOTION_SPEED)
            shift = np.linalg.norm(cell.block_positions() - self.tower, axis=1).max()
            if not moving or shift < self.settings.start_shift:
                return
            self.start = cell.sim_time
        if cell.sim_time + 1e-6 >= self.start + len(self.frames) * self.settings.frame_interval:
            self.grab(cell)

    def grab(self, cell: Any) -> None:
        from panda_grasp_env.perception.segmentation import colour_masks

        sensors = self.env.unwrapped.sensors
        sensors.invalidate()
        rgb, depth = sensors.rgbd("overhead")
        segmentation = sensors.segmentation("overhead")
        u0, v0 = self.origin
        window = (slice(v0, v0 + self.settings.crop), slice(u0, u0 + self.settings.crop))
        n_blocks = len(cell.block_ids)
        labels = np.where((segmentation >= 2) & (segmentation < 2 + n_blocks), segmentation - 1, 0).astype(np.uint8)
        rgb_crop = np.ascontiguousarray(rgb[window])
        colour = np.zeros(rgb_crop.shape[:2], dtype=np.uint8)
        for index, mask in enumerate(colour_masks(rgb_crop, self.colours).values()):
            colour[mask] = index + 1
        poses = np.concatenate([cell.data.xpos[cell.block_ids], cell.data.xquat[cell.block_ids]], axis=1)
        self.frames.append(
            {
                "rgb": rgb_crop,
                "depth": depth[window].astype(np.float16),
                "labels": labels[window],
                "colour_labels": colour,
                "poses": poses.astype(np.float32),
            }
        )
        sensors.invalidate()


def make_recorder_env(n_blocks: int) -> Any:
    """The env that records towers of ``n_blocks``: block i (label i + 1) has ``DEFAULT_COLOURS``' colour i."""
    import gymnasium as gym

    import panda_grasp_env  # noqa: F401

    return gym.make(
        "PandaTowerBreak-v0",
        n_blocks=n_blocks,
        action_mode="primitive",
        primitive_z=True,
        allow_impulse=True,
        obs_mode="state",
        cameras=("overhead",),
        image_size=RENDER_SIZE,
    )


class RecorderEnvs(dict):
    """Recorder envs by tower height (blocks), each made when first asked for."""

    def __missing__(self, n_blocks: int) -> Any:
        self[n_blocks] = env = make_recorder_env(n_blocks)
        return env


def tower_height(seed: int, settings: RecorderSettings) -> int:
    """The tower height (blocks) of sequence ``seed``: one of ``settings.tower_blocks``, uniformly, from a
    generator of the sequence's own, apart from the one that draws its strike (so a single height records
    exactly what the recorder did before heights were a setting)."""
    rng = np.random.default_rng([settings.seed, seed, 0x70E5])
    return int(settings.tower_blocks[int(rng.integers(len(settings.tower_blocks)))])


def record_sequence(envs: RecorderEnvs, seed: int, settings: RecorderSettings) -> dict[str, np.ndarray]:
    """One fall: reset the env of the sequence's ``tower_height`` with ``seed``, break the tower, grab
    ``settings.frames`` frames.  ``poses`` has a row per block of the tallest of ``settings.tower_blocks``:
    NaN for the blocks a lower tower lacks."""
    from panda_grasp_env.actions import encode_primitive

    n_blocks = tower_height(seed, settings)
    env = envs[n_blocks]
    _, info = env.reset(seed=seed)
    cell = env.unwrapped.cell
    rng = np.random.default_rng([settings.seed, seed, 0xFA11])
    camera = env.unwrapped.camera_model("overhead")
    tower = cell.block_positions()
    base = tower[np.argmin(tower[:, 2])]
    (u, v), _ = camera.world_to_pixel(np.array([base[0], base[1], 0.0]))
    half = settings.crop // 2
    origin = (
        int(np.clip(round(u) - half, 0, RENDER_SIZE[0] - settings.crop)),
        int(np.clip(round(v) - half, 0, RENDER_SIZE[1] - settings.crop)),
    )
    breaker = settings.breaker if settings.breaker != "mixed" else ("impulse", "push")[int(rng.integers(2))]
    lowest, highest = settings.strike_levels
    level = int(rng.integers(lowest, min(highest, len(tower) - 1) + 1))
    heading = float(rng.uniform(-np.pi, np.pi))
    order = np.argsort(tower[:, 2])
    target = tower[order[level]]
    primitives = info["action_layout"]["primitives"]
    if breaker == "impulse":
        magnitude = float(rng.uniform(*settings.impulse))
        action = encode_primitive(primitives, True, "impulse", target[0], target[1], heading, target[2])
        actions = env.unwrapped.actions  # this sequence's impulse strength
        actions.settings = replace(actions.settings, impulse_magnitude=magnitude)
    else:
        magnitude = 0.0
        start = target[:2] - 0.08 * np.array([np.cos(heading), np.sin(heading)])
        action = encode_primitive(primitives, True, "push", start[0], start[1], heading, target[2])
    grabber = FrameGrabber(env, settings, origin, info["block_colours"], tower)
    cell.physics.add_observer(grabber.on_control_step)
    try:
        env.step(action)
        deadline = cell.sim_time + settings.frames * settings.frame_interval + 2.0
        while not grabber.done and cell.sim_time < deadline:
            cell.wait(cell.physics.control_dt)
        if grabber.start is None:  # nothing moved (a glancing push): record the standing tower
            grabber.start = cell.sim_time
        while not grabber.done:
            cell.wait(cell.physics.control_dt)
    finally:
        cell.physics.remove_observer(grabber.on_control_step)
    stacked = {key: np.stack([frame[key] for frame in grabber.frames]) for key in grabber.frames[0]}
    missing = max(settings.tower_blocks) - n_blocks
    stacked["poses"] = np.pad(stacked["poses"], ((0, 0), (0, missing), (0, 0)), constant_values=np.nan)
    return {
        **stacked,
        "n_blocks": np.uint8(n_blocks),
        "seeds": np.int64(seed),
        "breaker": np.uint8(BREAKERS.index(breaker)),
        "strike": np.array([level, heading, magnitude, target[0], target[1]], dtype=np.float32),
        "crop_origin": np.array(origin, dtype=np.int32),
    }


#: This process's recorder envs (a pool worker's, or the recording process's own with one worker).
_ENVS = RecorderEnvs()
_STRUCTURES: list[StructureRecorder] = []  # this process's structure recorder, made when first needed


def structure_recorder() -> StructureRecorder:
    if not _STRUCTURES:
        _STRUCTURES.append(StructureRecorder())
    return _STRUCTURES[0]


def record_one(seed: int, settings: RecorderSettings) -> dict[str, np.ndarray]:
    """Sequence ``seed`` of the settings' scene."""
    if settings.scene == "structures":
        return structure_recorder().record(seed, settings)
    return record_sequence(_ENVS, seed, settings)


def record_shard(job: tuple[Path, int, int, RecorderSettings]) -> dict[str, Any]:
    """Record sequences [first, first + count) into ``out/shard_<index>.npz`` and its sidecar JSON (both atomic)."""
    out, index, count, settings = job
    began = time.perf_counter()
    first = settings.seed + index * settings.shard_size
    sequences = [record_one(first + i, settings) for i in range(count)]
    names = [*SHARD_ARRAYS, *(STRUCTURE_ARRAYS if settings.scene == "structures" else ())]
    arrays = {key: np.stack([s[key] for s in sequences]) for key in names}
    name = f"shard_{index:05d}.npz"
    with atomic_path(out / name) as tmp, open(tmp, "wb") as handle:
        np.savez_compressed(handle, **arrays)
    entry = {
        "file": name,
        "sequences": count,
        "first_seed": first,
        "bytes": (out / name).stat().st_size,
        "sha256": sha256(out / name),
        "seconds": round(time.perf_counter() - began, 2),
    }
    write_atomically(out / f"{name}.json", json.dumps(entry))
    return entry


def finished_shard(out: Path, index: int, count: int) -> dict[str, Any] | None:
    """The sidecar of a shard already on disk and intact, else None."""
    name = f"shard_{index:05d}.npz"
    sidecar = out / f"{name}.json"
    if not sidecar.is_file() or not (out / name).is_file():
        return None
    entry = read_json(sidecar, MAX_DOCUMENT_BYTES)
    if (
        entry["sequences"] != count
        or (out / name).stat().st_size != entry["bytes"]
        or sha256(out / name) != entry["sha256"]
    ):
        return None
    return entry


def record_dataset(
    out: Path, sequences: int, settings: RecorderSettings, workers: int = 1, progress: bool = True
) -> dict[str, Any]:
    """Record ``sequences`` sequences into ``out``; returns the metadata (also written to ``out/metadata.json``)."""
    from tqdm import tqdm

    if sequences < 1 or workers < 1:
        raise ValueError(f"sequences and workers must be >= 1, got {sequences} and {workers}")
    out.mkdir(parents=True, exist_ok=True)
    settings_file = out / "settings.json"
    wanted = {"sequences": sequences, **asdict(settings)}
    # A folder recorded before LATER_SETTINGS existed was recorded as their defaults record.
    defaults = {key: value for key, value in asdict(RecorderSettings()).items() if key in LATER_SETTINGS}
    recorded = (
        json.loads(json.dumps(defaults)) | read_json(settings_file, MAX_DOCUMENT_BYTES)
        if settings_file.exists()
        else None
    )
    if recorded is not None and recorded != json.loads(json.dumps(wanted)):
        raise ValueError(f"{out} holds a recording with other settings ({settings_file}); use another --out")
    settings_file.write_text(json.dumps(wanted, indent=2))
    n_shards = -(-sequences // settings.shard_size)
    counts = [min(settings.shard_size, sequences - i * settings.shard_size) for i in range(n_shards)]
    entries: dict[int, dict[str, Any]] = {}
    jobs = []
    for index, count in enumerate(counts):
        entry = finished_shard(out, index, count)
        if entry is not None:
            entries[index] = entry
        else:
            jobs.append((out, index, count, settings))
    began = time.perf_counter()
    bar = tqdm(total=sequences, initial=sum(e["sequences"] for e in entries.values()), unit="seq", disable=not progress)
    try:
        if workers == 1 or len(jobs) <= 1:
            results = map(record_shard, jobs)
            for entry in results:
                entries[int(entry["file"][6:11])] = entry
                bar.update(entry["sequences"])
        else:
            with multiprocessing.get_context("spawn").Pool(workers) as pool:
                for entry in pool.imap_unordered(record_shard, jobs):
                    entries[int(entry["file"][6:11])] = entry
                    bar.update(entry["sequences"])
    finally:
        bar.close()
    seconds = time.perf_counter() - began
    recorded = sum(job[2] for job in jobs)
    metadata = describe(out, settings, sequences, [entries[i] for i in range(n_shards)])
    metadata["recording"] = {
        "sequences_recorded_now": recorded,
        "seconds": round(seconds, 1),
        "workers": workers,
        "sequences_per_second": round(recorded / seconds, 2) if recorded else None,
    }
    write_atomically(out / "metadata.json", json.dumps(metadata, indent=2))
    return metadata


def describe(out: Path, settings: RecorderSettings, sequences: int, shards: list[dict[str, Any]]) -> dict[str, Any]:
    import importlib.metadata as md

    if settings.scene == "structures":
        camera = structure_recorder().camera()
        classes = ["background", *(f"piece {rank} (highest first)" for rank in range(1, MAX_PIECES + 1))]
        heights = list(range(1, MAX_PIECES + 1))
    else:
        env = make_recorder_env(max(settings.tower_blocks))  # its colours are every height's first colours
        _, info = env.reset(seed=settings.seed)
        camera = env.unwrapped.camera_model("overhead")
        classes = ["background", *info["block_colours"]]
        heights = list(settings.tower_blocks)
        env.close()
    counts = {split: 0 for split in ("train", "val", "test")}
    for entry in shards:
        for seed in range(entry["first_seed"], entry["first_seed"] + entry["sequences"]):
            counts[split_of(seed)] += 1
    return {
        "sequences": sequences,
        "frames": settings.frames,
        "frame_interval": settings.frame_interval,
        "crop": settings.crop,
        "tower_blocks": heights,
        "scene": settings.scene,
        "classes": classes,
        "settings": asdict(settings),
        "splits": {"rule": "seed % 10: 0-7 train, 8 val, 9 test", **counts},
        "camera": {
            "name": "overhead",
            "render_size": list(RENDER_SIZE),
            "K": camera.K.tolist(),
            "rotation": camera.rotation.tolist(),
            "position": camera.position.tolist(),
            "crop": "each sequence's crop_origin (column, row) shifts the principal point by minus that",
        },
        "versions": {p: md.version(p) for p in ("mujoco", "numpy", "gymnasium")}
        | {"python": platform.python_version()},
        "shards": shards,
    }


def int_tuple(text: str) -> tuple[int, ...]:
    """``"6,8"`` -> ``(6, 8)`` (a command-line list)."""
    return tuple(int(part) for part in text.split(","))


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(
        prog="python -m panda_grasp_env.falls",
        description=__doc__,
        formatter_class=argparse.RawDescriptionHelpFormatter,
    )
    parser.add_argument("--out", type=Path, default=Path("data/falls"))
    parser.add_argument("--sequences", type=int, default=2000)
    parser.add_argument("--workers", type=int, default=2)
    defaults = RecorderSettings()
    for field, value in asdict(defaults).items():
        if field == "impulse":
            parser.add_argument("--impulse", type=float, nargs=2, default=value, metavar=("LOW", "HIGH"))
        elif field == "tower_blocks":
            parser.add_argument(
                "--tower-blocks",
                type=int_tuple,
                default=value,
                metavar="N[,N...]",
                help="tower heights in blocks, one drawn per sequence (default 4)",
            )
        elif field == "strike_levels":
            parser.add_argument("--strike-levels", type=int, nargs=2, default=value, metavar=("LOWEST", "HIGHEST"))
        elif isinstance(value, bool):
            parser.add_argument(f"--{field.replace('_', '-')}", action="store_true")
        else:
            parser.add_argument(f"--{field.replace('_', '-')}", type=type(value), default=value)
    parser.add_argument("--no-progress", action="store_true")
    args = parser.parse_args(argv)
    interrupt_on_signals()
    try:
        settings = checked_config(RecorderSettings, {f: getattr(args, f) for f in asdict(defaults)}, "the command line")
        metadata = record_dataset(args.out, args.sequences, settings, args.workers, not args.no_progress)
    except ValueError as error:
        print(f"error: {error}", file=sys.stderr)
        return 2
    except KeyboardInterrupt:
        print(f"\ninterrupted: finished shards are kept in {args.out}; rerun the same command to record the rest")
        return 130
    rec = metadata["recording"]
    print(
        f"{metadata['sequences']} sequences in {args.out} ({metadata['splits']}); recorded {rec['sequences_recorded_now']} "
        f"now in {rec['seconds']} s with {rec['workers']} workers: {rec['sequences_per_second']} sequences/s"
    )
    return 0


if __name__ == "__main__":
    sys.exit(main())
