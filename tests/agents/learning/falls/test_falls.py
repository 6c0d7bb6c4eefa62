"""The fall-dynamics model: the loader of recorded datasets, the ConvLSTM, its metrics and baselines, and its
training runs through train.py (the recorder's tests: ``tests/falls/``)."""

import dataclasses
import json
import re

import numpy as np
import pytest
import torch
import yaml

from panda_grasp_env.agents.learning.falls import records as fall_records
from panda_grasp_env.agents.learning.falls import training as fall_training
from panda_grasp_env.agents.learning.falls.baselines import constant_velocity, copy_last
from panda_grasp_env.agents.learning.falls.config import fall_config
from panda_grasp_env.agents.learning.falls.dataset import FallSequences, load_split
from panda_grasp_env.agents.learning.falls.directions import fall_directions, image_to_world_direction
from panda_grasp_env.agents.learning.falls.metrics import Confusion, evaluate
from panda_grasp_env.agents.learning.falls.model import FallPredictor, load_fall_model
from panda_grasp_env.agents.learning.falls.records import tower_words
from panda_grasp_env.agents.learning.falls.settling import (
    classification,
    dihedral,
    fit_settle_head,
    largest_shifts,
    settle_scores,
)
from panda_grasp_env.commands import train
from panda_grasp_env.falls.shards import split_of


def tiny_fall_run(dataset, batch_size=4):
    """Overrides that make ``configs/fall_convlstm.yaml`` a run of seconds on the recorded ``dataset``."""
    return [f"dataset={dataset}", "hidden=8", f"batch_size={batch_size}", "torch_threads=1", "context=3", "rollout=3"]


@pytest.mark.unit
def test_a_dataset_recorded_before_tower_heights_loads_as_four_block_towers(fall_dataset, tmp_path):
    from panda_grasp_env.tooling.runs import sha256

    meta = json.loads((fall_dataset / "metadata.json").read_text())
    for entry in meta["shards"]:
        with np.load(fall_dataset / entry["file"]) as shard:
            np.savez_compressed(tmp_path / entry["file"], **{k: shard[k] for k in shard.files if k != "n_blocks"})
        entry.update(bytes=(tmp_path / entry["file"]).stat().st_size, sha256=sha256(tmp_path / entry["file"]))
    del meta["tower_blocks"]
    (tmp_path / "metadata.json").write_text(json.dumps(meta))
    split = load_split(tmp_path, "train")
    assert split.n_blocks.tolist() == [4] * len(split.labels) and split.poses.shape[2] == 4


@pytest.mark.unit
def test_loader_splits_by_sequence_and_names_a_corrupt_shard(fall_dataset, tmp_path):
    train_split = load_split(fall_dataset, "train")
    test_split = load_split(fall_dataset, "test")
    assert all(split_of(int(s)) == "train" for s in train_split.seeds)
    assert set(train_split.seeds).isdisjoint(test_split.seeds)
    assert len(train_split.labels) + len(test_split.labels) + len(load_split(fall_dataset, "val").labels) == 10
    copy = tmp_path / "copy"
    copy.mkdir()
    for f in fall_dataset.iterdir():
        (copy / f.name).write_bytes(f.read_bytes())
    data = bytearray((copy / "shard_00003.npz").read_bytes())
    data[100] ^= 0xFF
    (copy / "shard_00003.npz").write_bytes(bytes(data))
    with pytest.raises(ValueError, match="shard shard_00003.npz is corrupt"):
        load_split(copy, "train")
    (copy / "shard_00002.npz").write_bytes(bytes(data[:50]))
    with pytest.raises(ValueError, match="shard shard_00002.npz is truncated"):
        load_split(copy, "train")
    with pytest.raises(ValueError, match="unknown split"):
        load_split(fall_dataset, "training")


def moving_square(length=8, size=16, step=2):
    """A block (class 1) moving right by ``step`` pixels per frame."""
    frames = np.zeros((length, size, size), dtype=np.uint8)
    for t in range(length):
        frames[t, 6:10, t * step : t * step + 4] = 1
    return frames


@pytest.mark.unit
def test_baselines_and_metrics_on_a_moving_square():
    frames = moving_square()
    assert np.array_equal(constant_velocity(frames, 3, 2), frames[5])
    assert np.array_equal(copy_last(frames, 3, 1), frames[3])
    confusion = Confusion(2)
    confusion.add(frames[4], copy_last(frames, 3, 1))
    summary = confusion.summary(["background", "red"])
    assert summary["iou"]["red"] == pytest.approx(2 / 6, abs=1e-4)  # 4x4 squares overlapping by 2 columns
    assert summary["foreground_accuracy"] == pytest.approx(0.5, abs=1e-4)
    results = evaluate(None, frames[None], ["background", "red"], context=2)
    assert results["constant_velocity"]["t+5"]["mean_block_iou"] == pytest.approx(1.0)


#: A 32x32 camera 1 m above the world origin, with the overhead camera's axes: image right is world -y, image
#: down world -x, the optical axis world -z (a block on the table 1 cm along -y is 1 pixel right of centre).
TOP_DOWN = {
    "render_size": [32, 32],
    "K": [[100.0, 0, 15.5], [0, 100.0, 15.5], [0, 0, 1]],
    "rotation": [[0, -1, 0], [-1, 0, 0], [0, 0, -1]],
    "position": [0.0, 0.0, 1.0],
}


def directions(labels, poses, n_blocks, model=None):
    """``fall_directions`` of 32x32 label sequences cut at the corner of ``TOP_DOWN``'s image."""
    origins = np.zeros((len(labels), 2), dtype=int)
    return fall_directions(model, labels, poses, np.array(n_blocks), origins, TOP_DOWN, ["bg", "red"], context=3)


@pytest.mark.unit
def test_fall_direction_scores_a_blob_moving_the_way_the_blocks_went_and_the_opposite_way():
    frames = np.zeros((1, 8, 32, 32), dtype=np.uint8)
    for t in range(8):
        frames[0, t, 12:18, 2 + 2 * t : 8 + 2 * t] = 1  # moving right in the image: towards world -y
    assert np.allclose(image_to_world_direction(np.array([0.0, 2.0]), TOP_DOWN), [0.0, -0.02])
    poses = np.zeros((1, 8, 2, 7), dtype=np.float32)
    poses[0, :, 0, 1] = -0.01 * np.arange(8)  # block 0 went 7 cm along world -y; block 1 (unused at n_blocks 1) stood
    model = FallPredictor(2, 32, context=3, hidden=8)  # untrained: constant velocity, soft edges
    right = directions(frames, poses, [1], model)
    assert (right["fell"], right["did_not_fall"], right["hidden"], right["scored"]) == (1, 0, 0, 1)
    for name in ("copy_last", "constant_velocity", "translation_oracle", "true_labels"):
        assert right["predictors"][name] == {"within_45": 1.0, "median_error_deg": 0.0, "no_direction": 0}, name
    # The untrained model's soft edges drift its five-step rollout a row downwards.
    assert right["predictors"]["model"]["within_45"] == 1.0 and right["predictors"]["model"]["median_error_deg"] < 10
    wrong = directions(frames, -poses, [1])
    assert wrong["predictors"]["constant_velocity"] == {"within_45": 0.0, "median_error_deg": 180.0, "no_direction": 0}
    # A tower that did not fall is counted apart, by height too (n_blocks 6 and 8: both blocks count); so is one
    # whose struck block flew out of view while the rest stood (its blocks' mean moved 50 cm), and one the first
    # frame does not show.
    still = np.repeat(frames[:, :1], 8, axis=1)
    flung = np.zeros_like(poses)
    flung[0, -1, 1, 1] = -1.0
    hidden = frames.copy()
    hidden[0, 0] = 0
    both = directions(
        np.concatenate([frames, still, still, hidden]), np.concatenate([poses, 0 * poses, flung, poses]), [6, 8, 8, 6]
    )
    assert (both["sequences"], both["did_not_fall"], both["fell"], both["hidden"], both["scored"]) == (4, 2, 2, 1, 1)
    assert (both["by_height"]["8"]["did_not_fall"], both["by_height"]["8"]["fell"]) == (2, 0)
    assert both["by_height"]["8"]["predictors"]["copy_last"]["within_45"] is None
    # A prediction that does not move has no direction: a 180-degree miss.
    standing = directions(still, poses, [1])
    assert standing["predictors"]["copy_last"] == {"within_45": 0.0, "median_error_deg": 180.0, "no_direction": 1}


@pytest.mark.unit
def test_model_rollout_shapes_and_mismatch_errors():
    model = FallPredictor(n_classes=5, image_size=16, context=2, hidden=8)
    frames = torch.zeros(3, 2, 5, 16, 16)
    assert model.rollout(frames, 4).shape == (3, 4, 5, 16, 16)
    with pytest.raises(ValueError, match="expects 16x16 frames"):
        evaluate(model, np.zeros((1, 10, 32, 32), dtype=np.uint8), ["b", "1", "2", "3", "4"], context=2)
    with pytest.raises(ValueError, match="predicts 5 classes"):
        evaluate(model, np.zeros((1, 10, 16, 16), dtype=np.uint8), ["b", "1"], context=2)


def test_fall_training_runs_resumes_reports_and_ships(fall_dataset, tmp_path, capsys, monkeypatch):
    config = "configs/fall_convlstm.yaml"
    common = tiny_fall_run(fall_dataset)
    assert train.main(["--config", config, "--runs", str(tmp_path), "--no-progress", *common, "epochs=1"]) == 0
    run = tmp_path / "fall_convlstm-seed0"
    assert train.main(["--resume", str(run), "hidden=16", "--no-progress"]) == 2  # the saved weights are 8 wide
    assert train.main(["--resume", str(run), "epochs=2", "--no-progress"]) == 0
    rows = [json.loads(line) for line in (run / "evaluations.jsonl").read_text().splitlines()]
    assert [r["epoch"] for r in rows] == [1, 2]
    final = json.loads((run / "final.json").read_text())
    assert set(final["metrics"]) == {"model", "copy_last", "constant_velocity", "translation_oracle"}
    assert set(final["direction"]["predictors"]) == {*final["metrics"], "true_labels"}
    assert list((run / "strips").glob("seed*.png"))
    card = (run / "card.md").read_text()
    assert "mean block IoU" in card and "resumed with `epochs=2`" in card
    assert "falling 4-block tower" in card and "| true_labels | all |" in card
    assert tower_words([6, 8]) == "6- or 8-block" and tower_words([4, 6, 8]) == "4-, 6- or 8-block"
    model, saved = load_fall_model(run / "best.pt")
    assert model.context == 3 and model.use_depth and saved["classes"][0] == "background"
    assert load_split(fall_dataset, "val", depth=True).depth.dtype == np.float16
    monkeypatch.setattr(fall_records, "FALL_CHECKPOINTS", tmp_path / "shipped")
    assert train.main(["--ship", str(run), "--name", "tiny", "--avoid-failures"]) == 2  # no FailureMemory here
    assert train.main(["--ship", str(run), "--name", "tiny"]) == 0
    shipped, _ = load_fall_model(tmp_path / "shipped" / "tiny" / "model.pt")
    assert shipped.describe() == model.describe() and (tmp_path / "shipped" / "tiny" / "card.md").exists()
    assert "constant_velocity" in capsys.readouterr().out
    assert train.main(["--config", config, "--runs", str(tmp_path), "dataset=/nowhere"]) == 2
    (run / "broken.pt").write_bytes(b"x")
    with pytest.raises(ValueError, match="cannot load fall-dynamics checkpoint"):
        load_fall_model(run / "broken.pt")
    older = {**torch.load(run / "best.pt", weights_only=True), "architecture": 1}
    torch.save(older, run / "older.pt")
    with pytest.raises(ValueError, match="architecture 1; this code runs architecture"):
        load_fall_model(run / "older.pt")
    # Any fall model scores on any recorded dataset's test split: a run, and the shipped copy, on this one.
    assert train.main(["--retest", str(run)]) == 0 and train.main(["--retest", str(tmp_path / "shipped" / "tiny")]) == 0
    assert "constant_velocity" in capsys.readouterr().out
    retests = json.loads((run / "retest.json").read_text())
    assert retests[str(fall_dataset)]["metrics"]["model"] == final["metrics"]["model"]  # the final test, again
    assert retests[str(fall_dataset)]["direction"] == final["direction"]
    assert train.main(["--retest", str(run), "dataset=/nowhere"]) == 2
    assert train.main(["--retest", str(run), "epochs=3"]) == 2
    # A latest.pt changed since this user's job wrote it is not resumed from (nor one of a copied run).
    torch.save({**torch.load(run / "latest.pt", weights_only=True), "epoch": 0}, run / "latest.pt")
    assert train.main(["--resume", str(run), "epochs=3", "--no-progress"]) == 2
    assert "latest.pt was not written by this user's job in this folder" in capsys.readouterr().err


@pytest.mark.unit
def test_untrained_model_moves_each_block_by_its_own_velocity_and_displacement_targets_agree():
    from panda_grasp_env.agents.learning.falls.model import FallPredictor, block_displacements, one_hot

    labels = torch.zeros(1, 3, 32, 32, dtype=torch.long)
    for t in range(3):
        labels[0, t, 10:16, 4 + 2 * t : 10 + 2 * t] = 1  # block 1 moves 2 px a frame along x (columns)
        labels[0, t, 20:26, 20:26] = 2  # block 2 stands still
    model = FallPredictor(3, 32, context=3, hidden=8)
    predicted = model.rollout(one_hot(labels, 3), 1)[0, 0].argmax(0)
    expected = torch.zeros(32, 32, dtype=torch.long)
    expected[10:16, 10:16], expected[20:26, 20:26] = 1, 2
    assert torch.equal(predicted, expected)
    target, area = block_displacements(labels[:, 1], labels[:, 2], 3)
    assert torch.allclose(target[0], torch.tensor([[2.0, 0.0], [0.0, 0.0]])) and area[0].tolist() == [36, 36]
    # Classes the frames do not show still get their row (a structure of fewer pieces than the model's classes).
    assert block_displacements(labels[:, 1], labels[:, 2], 5)[1][0].tolist() == [36, 36, 0, 0]
    labels[0, 2][labels[0, 2] == 2] = 0  # block 2 gone: no displacement to learn from
    assert block_displacements(labels[:, 1], labels[:, 2], 3)[1][0].tolist() == [36, 0]


@pytest.mark.unit
def test_an_anchored_model_starts_as_copy_last_and_shifts_the_newest_true_frame_by_the_summed_displacements():
    """Untrained, an anchored model copies the last frame; taught a motion of 2 px a frame, its fifth frame is
    the newest true frame shifted 10 px, sharp (one warp, not five), and the training loss compares the summed
    displacements with the blocks' displacement from that frame."""
    from panda_grasp_env.agents.learning.falls.model import one_hot

    labels = torch.zeros(1, 3, 32, 32, dtype=torch.long)
    for t in range(3):
        labels[0, t, 10:16, 4 + 2 * t : 10 + 2 * t] = 1  # block 1 moves 2 px a frame along x (columns)
        labels[0, t, 20:26, 20:26] = 2  # block 2 stands still
    model = FallPredictor(3, 32, context=3, hidden=8, anchored=True)
    assert model.describe()["anchored"] and not FallPredictor(3, 32, context=3).anchored
    frames = one_hot(labels, 3)
    logits, motions, _ = model.rollout_with_motion(frames, 5)
    assert all(torch.equal(logits[0, h].argmax(0), labels[0, 2]) for h in range(5)) and not motions.any()
    with torch.no_grad():
        model.motion[-1].bias.copy_(torch.tensor([0.5, 0.0]))  # half a pixel a frame: bilinear blur each step
    logits, motions, _ = model.rollout_with_motion(frames, 4)
    expected = torch.zeros(32, 32, dtype=torch.long)
    expected[10:16, 8 + 2 : 14 + 2], expected[20:26, 20 + 2 : 26 + 2] = 1, 2
    assert torch.equal(logits[0, 3].argmax(0), expected)  # 4 x 0.5 px from frame 2, no block lost to blur
    assert torch.allclose(motions[0].sum(0), torch.tensor([[2.0, 0.0], [2.0, 0.0]]))


def moving_block_labels() -> torch.Tensor:
    """(1, 3, 32, 32): block 1 moving 2 px a frame along x (columns), block 2 standing still."""
    labels = torch.zeros(1, 3, 32, 32, dtype=torch.long)
    for t in range(3):
        labels[0, t, 10:16, 4 + 2 * t : 10 + 2 * t] = 1
        labels[0, t, 20:26, 20:26] = 2
    return labels


@pytest.mark.unit
def test_track_features_read_each_block_own_track_and_the_others_highest_first():
    from panda_grasp_env.agents.learning.falls.model import one_hot
    from panda_grasp_env.agents.learning.falls.tracks import block_tracks, track_feature_count, track_features

    frames = one_hot(moving_block_labels(), 3)
    centre, area, height = block_tracks(frames, 3)
    assert torch.allclose(centre[0, :, 0], torch.tensor([[6.5, 12.5], [8.5, 12.5], [10.5, 12.5]]))
    assert area[0].tolist() == [[36, 36]] * 3 and not height.any()
    height[..., 1] = 1.0  # block 2 stands higher: it comes first among the neighbours
    features = track_features(centre, area, height, 32)
    assert features.shape == (1, 2, track_feature_count(3, 2))
    assert features[0, 0, :6].tolist() == [2.0, 0.0, 1.0, 4.0, 0.0, 1.0]  # back 1 and 2 frames, in view
    assert features[0, 1, :6].tolist() == [0.0, 0.0, 1.0, 0.0, 0.0, 1.0]  # block 2 never moved
    neighbours = features[0, 0, -14:].view(2, 7)
    assert neighbours[:, 5].tolist() == [1.0, 0.0] and neighbours[:, 2].tolist() == [0.0, 2.0]
    assert torch.allclose(neighbours[1, :2], torch.zeros(2))  # itself, against itself
    assert torch.allclose(neighbours[0, :2], torch.tensor([1.2, 1.0]))  # block 2, tens of pixels from block 1


@pytest.mark.unit
def test_a_track_head_model_starts_as_copy_last_and_draws_every_frame_from_its_plan():
    from panda_grasp_env.agents.learning.falls.model import one_hot

    labels = moving_block_labels()
    with pytest.raises(ValueError, match="track_horizon must be 0, or >= 1 with anchored=True; got 3"):
        FallPredictor(3, 32, context=3, hidden=8, track_horizon=3)
    model = FallPredictor(3, 32, context=3, hidden=8, anchored=True, track_horizon=3)
    assert model.describe()["track_horizon"] == 3 and not hasattr(model, "motion")
    frames = one_hot(labels, 3)
    logits, motions, _ = model.rollout_with_motion(frames, 3)
    assert all(torch.equal(logits[0, h].argmax(0), labels[0, 2]) for h in range(3)) and not motions.any()
    with torch.no_grad():  # every block planned 2, 4, 6 px along x in the next three frames
        model.tracks.network[-1].bias.copy_(torch.tensor([2.0, 0.0, 4.0, 0.0, 6.0, 0.0]))
    logits, motions, _ = model.rollout_with_motion(frames, 3)
    expected = torch.zeros(32, 32, dtype=torch.long)
    expected[10:16, 14:20], expected[20:26, 26:32] = 1, 2
    assert torch.equal(logits[0, 2].argmax(0), expected)
    assert torch.allclose(motions[0, :, 0], torch.tensor([[2.0, 0.0]] * 3))  # steps between the planned frames
    with pytest.raises(ValueError, match="horizon 4 is past this model's track_horizon"):
        model.rollout(frames, 4)


@pytest.mark.unit
def test_windows_from_rest_start_with_the_first_frame_repeated_as_the_stability_check_asks():
    from types import SimpleNamespace

    labels = moving_block_labels().to(torch.uint8).numpy()  # block 1 moves 2 px a frame, block 2 stands
    model = FallPredictor(3, 32, context=2, hidden=8, anchored=True, track_horizon=2)
    split = SimpleNamespace(labels=labels, depth=None)
    plain = fall_training.track_windows(model, split, 2)
    rested = fall_training.track_windows(model, split, 2, from_rest=True)
    assert plain[3][:, 1].tolist() == [1, 1] and rested[3][:, 1].tolist() == [0, 0, 1, 1]
    first = rested[0][0]  # block 1 at t = 0, its context the first frame twice: no motion yet
    assert first[:2].tolist() == [0.0, 0.0] and first[2] == 1.0
    assert rested[1][0].tolist() == [[2.0, 0.0], [4.0, 0.0]]  # then it moves 2 and 4 px along x
    assert torch.equal(rested[0][2:], plain[0]) and torch.equal(rested[1][2:], plain[1])
    with pytest.raises(ValueError, match="track_windows_from_rest=True: expected false unless track_pretrain"):
        fall_config(
            {"kind": "fall_dynamics", "name": "tiny", "dataset": "x", "track_windows_from_rest": True}, "tiny.yaml"
        )


@pytest.mark.unit
def test_untrained_depth_model_carries_each_block_height_and_needs_depth():
    from panda_grasp_env.agents.learning.falls.model import model_inputs

    labels = np.zeros((1, 3, 32, 32), dtype=np.uint8)
    depth = np.full((1, 3, 32, 32), 1.0, dtype=np.float16)  # the table, 1 m below the camera
    for t in range(3):
        labels[0, t, 10:16, 4 + 2 * t : 10 + 2 * t] = 1  # a block 5 cm tall moving 2 px a frame
        depth[0, t, 10:16, 4 + 2 * t : 10 + 2 * t] = 0.95
    model = FallPredictor(3, 32, context=3, hidden=8, use_depth=True)
    logits, _, heights = model.rollout_with_motion(model_inputs(model, labels, depth), 2)
    assert torch.equal(logits[0, 0].argmax(0)[10:16, 10:16], torch.ones(6, 6, dtype=torch.long))
    assert heights.shape == (1, 2, 1, 32, 32)
    assert torch.allclose(
        heights[0, 0, 0, 11:15, 11:15], torch.ones(4, 4), atol=0.01
    )  # one block high (float16), moved
    assert heights[0, 0, 0, 20:, 20:].abs().max() < 1e-6
    with pytest.raises(ValueError, match="reads depth images"):
        model_inputs(model, labels)
    with pytest.raises(ValueError, match="reads depth images shaped like its labels"):
        evaluate(model, np.zeros((1, 10, 32, 32), dtype=np.uint8), ["b", "1", "2"], context=2)


def test_a_track_head_is_fitted_first_then_frozen_while_the_convlstm_trains_and_resumes(fall_dataset, tmp_path):
    config = "configs/fall_convlstm.yaml"
    common = tiny_fall_run(fall_dataset, batch_size=2)
    track = ["anchored_rollout=true", "track_head=true", "track_pretrain_epochs=3", "epoch_sequences=2"]
    args = ["--config", config, "--runs", str(tmp_path), "--no-progress", *common, *track, "val_sequences=1"]
    assert train.main([*args, "epochs=1"]) == 0
    run = tmp_path / "fall_convlstm-seed0"
    fitted = json.loads((run / "track_pretraining.json").read_text())
    assert fitted["epochs"] == 3 and len(fitted["validation_loss"]) == 3 and fitted["training_rows"] > 0
    first = torch.load(run / "latest.pt", weights_only=True)["model"]
    assert first["tracks.network.4.bias"].any()  # fitted: no longer the copy-last start
    assert train.main(["--resume", str(run), "epochs=2", "--no-progress"]) == 0
    model, _ = load_fall_model(run / "latest.pt")
    assert model.track_horizon == 7  # from the context to the last of 10 frames (the fall direction's rollout)
    after = torch.load(run / "latest.pt", weights_only=True)["model"]
    assert all(torch.equal(first[key], after[key]) for key in first if key.startswith("tracks."))
    assert not all(torch.equal(first[key], after[key]) for key in first if key.startswith("pooled_motion."))
    rows = [json.loads(line) for line in (run / "evaluations.jsonl").read_text().splitlines()]
    assert [r["epoch"] for r in rows] == [0, 1, 2] and rows[0]["loss"] is None  # 0: the fitted head, validated
    assert rows[0]["val"]["t+1"]["frames"] == 3  # one validation sequence, 3 windows
    assert "constant_velocity" in json.loads((run / "final.json").read_text())["metrics"]
    assert "track head fitted alone first: 3 epochs" in (run / "card.md").read_text()
    raw = {"kind": "fall_dynamics", "name": "tiny", "dataset": str(fall_dataset)}
    with pytest.raises(ValueError, match=r"config track_head=True: expected false unless anchored_rollout is true"):
        fall_config({**raw, "track_head": True}, "tiny.yaml")
    with pytest.raises(ValueError, match=r"config track_pretrain_epochs=2: expected 0 unless track_head is true"):
        fall_config({**raw, "track_pretrain_epochs": 2}, "tiny.yaml")


def synthetic_settles(n: int, seed: int) -> FallSequences:
    """``n`` one-frame-at-rest sequences of 32 px frames: a square block in the middle that falls (moves 5 cm by
    the last frame) when it is wide (12 px) and stands (0.5 mm) when it is narrow (6 px) -- a difference that no
    turn or mirror of the frame changes."""
    rng = np.random.default_rng(seed)
    labels = np.zeros((n, 3, 32, 32), dtype=np.uint8)
    poses = np.full((n, 3, 2, 7), np.nan, dtype=np.float32)
    wide = rng.random(n) < 0.5
    for i in range(n):
        half = 6 if wide[i] else 3
        centre = rng.integers(12, 20, size=2)
        labels[i, :, centre[0] - half : centre[0] + half, centre[1] - half : centre[1] + half] = 1
        poses[i, :, 0] = 0.0
        poses[i, -1, 0, 0] = 0.05 if wide[i] else 0.0005
    return FallSequences(
        labels, np.arange(n), ["background", "block_0", "block_1"], 0.08, poses, np.ones(n, dtype=np.int64),
        np.zeros((n, 2)), {},
    )  # fmt: skip


@pytest.mark.unit
def test_a_settle_head_learns_from_the_first_frame_what_falls_and_reports_it():
    torch.manual_seed(0)
    train_split, val_split = synthetic_settles(128, 0), synthetic_settles(64, 1)
    np.testing.assert_allclose(
        largest_shifts(val_split, 2), np.where(val_split.labels[:, 0].sum((1, 2)) > 100, 0.05, 5e-4)
    )
    with pytest.raises(ValueError, match=r"frames must be in 1..2"):
        largest_shifts(val_split, 3)
    model = FallPredictor(3, 32, 2, hidden=8, settle_frames=2)
    before = settle_scores(model, val_split)
    fitted = fit_settle_head(model, train_split, val_split, epochs=12)
    assert len(fitted["validation_loss"]) == 12 and fitted["training_sequences"] == 128
    assert min(fitted["validation_loss"]) < 0.5 * fitted["validation_loss"][0]
    after = settle_scores(model, val_split)
    assert after["accuracy"] >= 0.95 > before["accuracy"] and after == fitted["validation"]
    assert not any(p.requires_grad for p in model.settle.parameters())  # frozen for the ConvLSTM's epochs
    with pytest.raises(ValueError, match="no settle head"):
        FallPredictor(3, 32, 2, hidden=8).settle_shift(torch.zeros(1, 3, 32, 32))
    with pytest.raises(ValueError, match="settle_frames must be 0"):
        FallPredictor(3, 32, 2, settle_frames=-1)


@pytest.mark.unit
def test_stands_or_falls_is_scored_like_the_simulator_and_the_frame_symmetries_are_the_square_s():
    scored = classification(np.array([0.001, 0.005, 0.02, 0.0]), np.array([False, False, True, True]), 0.004)
    assert scored == {
        "sequences": 4, "falls": 2, "said_falls": 2, "precision": 0.5, "recall": 0.5, "accuracy": 0.5,
        "always_stands_accuracy": 0.5,
    }  # fmt: skip
    frame = torch.arange(16.0).view(1, 1, 4, 4)
    images = {tuple(dihedral(frame, k).flatten().tolist()) for k in range(8)}
    assert len(images) == 8 and tuple(frame.flatten().tolist()) in images
    assert torch.equal(dihedral(dihedral(frame, 1), 3), frame)


@pytest.mark.unit
def test_a_settle_head_is_fitted_in_a_training_run_frozen_after_and_on_its_card(fall_dataset, tmp_path, monkeypatch):
    fitted_heads = []

    def fit_and_keep(model, *args):
        result = fit_settle_head(model, *args)
        fitted_heads.append({k: v.clone() for k, v in model.settle.state_dict().items()})
        return result

    monkeypatch.setattr(fall_training, "fit_settle_head", fit_and_keep)
    config = "configs/fall_convlstm.yaml"
    args = ["--config", config, "--runs", str(tmp_path), "--no-progress", *tiny_fall_run(fall_dataset, batch_size=2)]
    assert train.main([*args, "epochs=1", "epoch_sequences=2", "val_sequences=1", "settle_epochs=2"]) == 0
    run = tmp_path / "fall_convlstm-seed0"
    fitted = json.loads((run / "settle_fitting.json").read_text())
    assert fitted["epochs"] == 2 and fitted["training_sequences"] == len(load_split(fall_dataset, "train").labels)
    model, _ = load_fall_model(run / "latest.pt")  # after the ConvLSTM's epoch
    assert model.settle_frames == 9  # the first of 10 frames to the last
    assert all(torch.equal(fitted_heads[0][k], v) for k, v in model.settle.state_dict().items())
    final = json.loads((run / "final.json").read_text())
    assert final["settle"]["sequences"] == len(load_split(fall_dataset, "test").labels)
    assert "settle head (will what was just set stand?), test split at 4 mm" in (run / "card.md").read_text()
    monkeypatch.setattr(fall_records, "FALL_CHECKPOINTS", tmp_path / "shipped")
    assert train.main(["--ship", str(run), "--name", "settled"]) == 0
    assert json.loads((tmp_path / "shipped" / "settled" / "settle_fitting.json").read_text()) == fitted


def test_labels_only_model_trains_without_depth(fall_dataset, tmp_path):
    """The config reads depth (``use_depth: true``, covered above); with it off the model reads labels only."""
    config = "configs/fall_convlstm.yaml"
    tiny = [*tiny_fall_run(fall_dataset), "epochs=1"]
    assert train.main(["--config", config, "--runs", str(tmp_path), "--no-progress", *tiny, "use_depth=false"]) == 0
    model, _ = load_fall_model(tmp_path / "fall_convlstm-seed0" / "best.pt")
    assert not model.use_depth
    split = load_split(fall_dataset, "val")
    assert split.depth is None
    assert evaluate(model, split.labels, split.classes, 3)["model"]["t+1"]["frames"] > 0
    assert train.main(["--config", config, "--runs", str(tmp_path), f"dataset={fall_dataset}", "use_depth=1"]) == 2


@pytest.mark.unit
def test_bad_fall_configs_fail_with_the_name_and_the_shipped_config_loads(fall_dataset, tmp_path):
    raw = {"kind": "fall_dynamics", "name": "tiny", "dataset": str(fall_dataset)}
    assert fall_config(raw, "tiny.yaml").context == 4
    with pytest.raises(ValueError, match=r"unknown key\(s\) \['epoch'\] in tiny.yaml; valid keys: \['kind'"):
        fall_config({**raw, "epoch": 3}, "tiny.yaml")
    with pytest.raises(ValueError, match=r"tiny.yaml lacks required key\(s\) \['dataset'\]"):
        fall_config({"kind": "fall_dynamics", "name": "tiny"}, "tiny.yaml")
    for key, value, expected in [
        ("kind", "policy", "'fall_dynamics'"),
        ("label_source", "rgb", "one of ['labels', 'colour_labels']"),
        ("epochs", 0, "an int >= 1"),
        ("context", True, "an int >= 1"),
        ("learning_rate", 1.5, "a number in (0, 1)"),
        ("motion_loss_weight", -1, "a number >= 0"),
        ("use_depth", 1, "true or false"),
        ("seed", -1, "an int >= 0"),
        ("max_minutes", 0, "a positive number or null"),
    ]:
        with pytest.raises(ValueError, match=re.escape(f"config {key}={value!r}: expected {expected}")):
            fall_config({**raw, key: value}, "tiny.yaml")
    with pytest.raises(ValueError, match="is not a fall dataset: metadata.json missing"):
        fall_config({**raw, "dataset": str(tmp_path)}, "tiny.yaml")
    # The shipped model's config, as its run saved it, reads back unchanged (its dataset is not here); keys added
    # since default to what it was trained with.
    saved = yaml.safe_load((fall_records.FALL_CHECKPOINTS / "fall_convlstm" / "config.yaml").read_text())
    config = fall_config({**saved, "dataset": str(fall_dataset)}, "config.yaml")
    added = {
        "anchored_rollout": False,
        "select_horizon": 1,
        "track_head": False,
        "track_pretrain_epochs": 0,
        "track_windows_from_rest": False,
        "settle_epochs": 0,
        "epoch_sequences": None,
        "val_sequences": None,
    }
    assert {**dataclasses.asdict(config), "dataset": saved["dataset"]} == saved | added


@pytest.mark.unit
@pytest.mark.parametrize("name", ["fall_convlstm", "fall_convlstm_tall"])
def test_a_shipped_fall_model_loads_and_beats_copying_the_last_frame_on_its_card(name):
    """Each shipped model beats copy-last on its held-out test at the horizon its best epoch was chosen on."""
    path = fall_records.FALL_CHECKPOINTS / name
    model, saved = load_fall_model(path / "model.pt")
    final = json.loads((path / "final.json").read_text())
    config = yaml.safe_load((path / "config.yaml").read_text())
    assert saved["classes"][0] == "background" and model.n_classes == len(saved["classes"])
    assert model.anchored == config.get("anchored_rollout", False)
    horizon = f"t+{config.get('select_horizon', 1)}"
    assert (
        final["metrics"]["model"][horizon]["mean_block_iou"] > final["metrics"]["copy_last"][horizon]["mean_block_iou"]
    )


@pytest.mark.unit
def test_every_fall_config_loads_with_its_dataset_swapped_for_a_recorded_one(fall_dataset):
    """The configs name datasets recorded on demand (their comments say how); every other key must check."""
    from testkit import CONFIGS

    paths = [path for path in CONFIGS.glob("*.yaml") if "kind: fall_dynamics" in path.read_text()]
    assert {"fall_convlstm_structures", "fall_convlstm_structures_settle"} <= {path.stem for path in paths}
    for path in paths:
        raw = {**yaml.safe_load(path.read_text()), "dataset": str(fall_dataset)}
        assert fall_config(raw, path.name).name == path.stem


@pytest.mark.unit
def test_the_shipped_settle_head_tells_falls_from_stands_better_than_always_answering_stands():
    """Its card's held-out test, and the validation it was kept on (its dataset is not in the repository)."""
    path = fall_records.FALL_CHECKPOINTS / "fall_convlstm_structures_settle"
    model, _ = load_fall_model(path / "model.pt")
    settle = json.loads((path / "final.json").read_text())["settle"]
    fitted = json.loads((path / "settle_fitting.json").read_text())
    assert model.settle_frames == 14 and settle["sequences"] == 640
    for scored in (settle, fitted["validation"]):
        assert scored["accuracy"] > scored["always_stands_accuracy"] and scored["recall"] > 0.8


def test_an_epoch_interrupted_during_its_validation_is_validated_on_resume(fall_dataset, tmp_path, monkeypatch):
    config = "configs/fall_convlstm.yaml"
    tiny = [*tiny_fall_run(fall_dataset), "epochs=1"]
    scoring = fall_training.evaluate

    def interrupted(*args, **kwargs):
        raise KeyboardInterrupt

    monkeypatch.setattr(fall_training, "evaluate", interrupted)
    assert train.main(["--config", config, "--runs", str(tmp_path), "--no-progress", *tiny]) == 130
    run = tmp_path / "fall_convlstm-seed0"
    assert not (run / "evaluations.jsonl").exists() and not (run / "best.pt").exists()
    monkeypatch.setattr(fall_training, "evaluate", scoring)
    assert train.main(["--resume", str(run), "--no-progress"]) == 0
    rows = [json.loads(line) for line in (run / "evaluations.jsonl").read_text().splitlines()]
    assert [row["epoch"] for row in rows] == [1] and (run / "best.pt").exists()
