import json

import imageio.v2 as imageio
import numpy as np

from panda_grasp_env.commands import evaluate
from panda_grasp_env.sim.workcell import Workcell
from panda_grasp_env.tooling.video import VideoRecorder


def test_demo_builds_and_breaks_a_tower(tmp_path):
    assert evaluate.main(["--demo", "--seed", "1", "--out", str(tmp_path), "--no-video"]) == 0
    summary = json.loads((tmp_path / "summary.json").read_text())
    assert summary["tower_built"] and summary["push"]["blocks_displaced"] >= 2
    assert [p["primitive"] for p in summary["primitives"]] == ["grasp", "place"] * 3


def test_video_recorder_writes_a_playable_mp4(tmp_path):
    cell = Workcell()
    cell.reset(np.random.default_rng(0))
    recorder = VideoRecorder(cell, tmp_path / "clip.mp4", width=160, height=120, every=1)
    recorder.caption = "test"
    cell.wait(0.4)
    assert not (tmp_path / "clip.mp4").exists()  # written as it goes, to a partial file
    path = recorder.save()
    frames = imageio.mimread(path)
    assert len(frames) == 10 and frames[0].shape == (120, 160, 3)
    assert not list(tmp_path.glob("*.partial*"))
    assert cell.physics.observers == (cell.collateral.on_control_step,)  # the recorder left


def test_caption_lines_stay_in_their_band_one_under_another():
    from panda_grasp_env.tooling.video import write_lines

    frame = np.full((360, 480, 3), 200, dtype=np.uint8)
    lines = ["push_grasp_mesh_dqn on GraspMeshClutterTest, seed 5000000", "grasp: ok", "t =  31.3 s"]
    write_lines(frame, lines)
    changed = np.flatnonzero((frame != 200).any(axis=(1, 2)))
    assert changed.min() == 0 and changed.max() < 90  # a band at the top, nothing drawn below it
    band = frame[: changed.max() + 1]
    ink_rows = np.flatnonzero((band > 200).any(axis=(1, 2)))  # white text on the darkened band
    runs = np.split(ink_rows, np.flatnonzero(np.diff(ink_rows) > 1) + 1)
    assert len(runs) == len(lines)  # each line on rows of its own
    ink_columns = np.flatnonzero((band > 200).any(axis=(0, 2)))
    assert ink_columns.max() < frame.shape[1] - 5  # the long line was drawn smaller to fit
