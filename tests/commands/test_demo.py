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
    recorder = VideoRecorder(cell, width=160, height=120, every=1)
    recorder.caption = "test"
    cell.wait(0.4)
    path = recorder.save(tmp_path / "clip.mp4")
    frames = imageio.mimread(path)
    assert len(frames) == 10 and frames[0].shape == (120, 160, 3)
    assert not list(tmp_path.glob("*.partial*"))
    assert cell.physics.observers == (cell.collateral.on_control_step,)  # the recorder left
