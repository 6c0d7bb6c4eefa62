"""The falling-tower recorder: its sequences, settings and shards, deterministic and resumable."""

import json

import numpy as np
import pytest
from testkit import FALL_RECORDING

from panda_grasp_env.agents.learning.falls.dataset import load_split
from panda_grasp_env.falls.recorder import RecorderEnvs, main, record_dataset, record_sequence, tower_height
from panda_grasp_env.falls.settings import LATER_SETTINGS, RecorderSettings
from panda_grasp_env.model.scene import DEFAULT_COLOURS
from panda_grasp_env.perception.camera import CameraModel
from panda_grasp_env.tooling.runs import checked_config

SETTINGS = RecorderSettings(**FALL_RECORDING)


def test_recording_holds_frames_poses_and_metadata(fall_dataset):
    meta = json.loads((fall_dataset / "metadata.json").read_text())
    assert meta["sequences"] == 10 and len(meta["shards"]) == 5
    assert meta["classes"][0] == "background" and len(meta["classes"]) == 5
    assert meta["recording"]["sequences_per_second"] > 0
    with np.load(fall_dataset / "shard_00000.npz") as shard:
        assert shard["rgb"].shape == (2, 10, 64, 64, 3)
        assert shard["labels"].shape == shard["colour_labels"].shape == (2, 10, 64, 64)
        assert shard["poses"].shape == (2, 10, 4, 7)
        labels, colour = shard["labels"], shard["colour_labels"]
        poses = shard["poses"]
    assert set(np.unique(labels)) <= {0, 1, 2, 3, 4} and (labels > 0).any()
    foreground = labels > 0
    assert (labels == colour)[foreground].mean() > 0.8  # perception's colour segmentation mostly agrees
    assert np.abs(poses[:, -1, :, :3] - poses[:, 0, :, :3]).max() > 0.02  # the towers fell


def test_recording_is_deterministic_and_resumes(fall_dataset, tmp_path):
    out = tmp_path / "again"
    record_dataset(out, 4, SETTINGS, workers=1, progress=False)
    first = json.loads((fall_dataset / "metadata.json").read_text())["shards"][:2]
    again = json.loads((out / "metadata.json").read_text())["shards"]
    assert [s["sha256"] for s in first] == [s["sha256"] for s in again]
    stamp = (out / "shard_00000.npz").stat().st_mtime_ns
    (out / "shard_00001.npz").write_bytes(b"broken")  # a shard cut short by a crash
    meta = record_dataset(out, 4, SETTINGS, workers=1, progress=False)
    assert meta["recording"]["sequences_recorded_now"] == 2  # only the broken shard again
    assert (out / "shard_00000.npz").stat().st_mtime_ns == stamp
    assert [s["sha256"] for s in meta["shards"]] == [s["sha256"] for s in first]
    with pytest.raises(ValueError, match="other settings"):
        record_dataset(out, 4, RecorderSettings(frames=12, shard_size=2, seed=7), workers=1, progress=False)
    # A folder recorded before the later settings existed resumes: their defaults record what it holds.
    settings = json.loads((out / "settings.json").read_text())
    (out / "settings.json").write_text(json.dumps({k: v for k, v in settings.items() if k not in LATER_SETTINGS}))
    assert record_dataset(out, 4, SETTINGS, workers=1, progress=False)["recording"]["sequences_recorded_now"] == 0


def recorder_settings(**raw):
    return checked_config(RecorderSettings, raw, "test settings")


@pytest.mark.unit
def test_bad_recorder_settings_fail_with_the_name():
    with pytest.raises(ValueError, match=r"config frame_interval=0\.05: expected a multiple of the 0\.04 s"):
        recorder_settings(frame_interval=0.05)
    with pytest.raises(ValueError, match="config breaker='kick': expected one of"):
        recorder_settings(breaker="kick")
    for heights in [(9,), (1,), (), (6, 6), (6.0,), (True,)]:
        with pytest.raises(ValueError, match="config tower_blocks="):
            recorder_settings(tower_blocks=heights)
    for levels in [(0, 6), (3, 2), (-1, 2), (0,)]:
        with pytest.raises(ValueError, match="config strike_levels="):
            recorder_settings(strike_levels=levels)
    with pytest.raises(ValueError, match="strike_levels.*lowest tower"):
        recorder_settings(tower_blocks=(4, 8), strike_levels=(4, 5))
    with pytest.raises(ValueError, match="start_shift"):
        recorder_settings(start_shift=-0.01)
    with pytest.raises(ValueError, match=r"unknown key\(s\) \['frame'\] in test settings; valid keys: \['frames'"):
        recorder_settings(frame=10)
    with pytest.raises(ValueError, match="frames"):
        RecorderSettings(frames=1)  # made directly, checked too
    assert recorder_settings(tower_blocks=[6, 8], impulse=[0.1, 0.3]) == RecorderSettings(
        tower_blocks=(6, 8), impulse=(0.1, 0.3)
    )  # lists, as config files and the command line give them, are tuples
    assert main(["--out", "/nonexistent/x", "--sequences", "0", "--no-progress"]) == 2
    assert main(["--out", "/nonexistent/x", "--tower-blocks", "6,9", "--no-progress"]) == 2


def test_tall_towers_draw_their_height_per_sequence_and_label_each_block_by_its_index(tmp_path):
    settings = RecorderSettings(frames=4, shard_size=2, tower_blocks=(6, 8), strike_levels=(3, 5))
    heights = [tower_height(seed, settings) for seed in range(40)]
    assert heights == [tower_height(seed, settings) for seed in range(40)] and set(heights) == {6, 8}
    assert heights[:2] == [6, 8]  # the two sequences recorded here
    meta = record_dataset(tmp_path, 2, settings, progress=False)
    assert meta["classes"] == ["background", *(f"block_{c}" for c in DEFAULT_COLOURS)]  # the tallest tower's
    assert meta["tower_blocks"] == [6, 8]
    camera = CameraModel(
        *meta["camera"]["render_size"], *(np.array(meta["camera"][k]) for k in ("K", "rotation", "position"))
    )
    with np.load(tmp_path / "shard_00000.npz") as shard:
        assert shard["n_blocks"].tolist() == [6, 8] and shard["poses"].shape == (2, 4, 8, 7)
        for labels, poses, n, origin in zip(shard["labels"], shard["poses"], shard["n_blocks"], shard["crop_origin"]):
            assert np.isnan(poses[:, n:]).all() and not np.isnan(poses[:, :n]).any()
            assert set(np.unique(labels)) <= set(range(n + 1))
            top = int(np.argmax(poses[0, :n, 2]))  # the standing tower's top block, seen from above before it falls
            (u, v), _ = camera.world_to_pixel(poses[0, top, :3] + [0, 0, 0.025])
            assert labels[0, round(v) - origin[1], round(u) - origin[0]] == top + 1
    split = load_split(tmp_path, "train")
    assert split.n_blocks.tolist() == [6, 8] and split.poses.shape == (2, 4, 8, 7)


def test_with_a_start_shift_the_frames_start_once_a_block_left_its_place():
    # Pushing fingers make a tall tower jitter faster than MOTION_SPEED long before it moves: without the shift
    # this sequence's first frame showed its blocks within 1 mm of the tower.
    settings = RecorderSettings(frames=2, tower_blocks=(8,), breaker="push", strike_levels=(4, 4), start_shift=0.005)
    envs = RecorderEnvs()
    first = record_sequence(envs, 2, settings)["poses"][0, :, :3]
    envs[8].reset(seed=2)
    assert np.linalg.norm(first - envs[8].unwrapped.cell.block_positions(), axis=1).max() >= 0.005
