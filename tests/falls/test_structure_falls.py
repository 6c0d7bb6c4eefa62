"""Structure falls (``panda_grasp_env/falls/structure_falls.py``): pieces set at their targets on a partly built
structure, recorded from rest in the falls dataset format, labelled by height as the learned check labels."""

import json

import numpy as np
import pytest

from panda_grasp_env.agents.learning.falls.dataset import load_split
from panda_grasp_env.falls.recorder import record_dataset
from panda_grasp_env.falls.settings import RecorderSettings
from panda_grasp_env.falls.structure_falls import CANDIDATE_KINDS, NOT_STRUCK, build_state
from panda_grasp_env.model.structure_generator import MAX_PIECES
from panda_grasp_env.model.structures import Piece, interpenetrate

SETTINGS = RecorderSettings(scene="structures", frames=8, frame_interval=0.08, crop=96, shard_size=6)


@pytest.mark.unit
def test_a_build_state_sets_supports_first_and_a_candidate_in_the_air_only_where_one_is_missing():
    span = [
        Piece("cube", (0.45, -0.045, 0.025)),
        Piece("cube", (0.45, 0.045, 0.025)),
        Piece("plank", (0.45, 0.0, 0.075), np.pi / 2),
    ]
    seen = set()
    offsets = []
    for seed in range(90):
        built, candidate, offset, kind = build_state(span, np.random.default_rng(seed), shifted=True)
        assert 2 not in built  # the plank is never set before both its cubes
        assert candidate not in built
        seen.add((len(built), candidate == 2))
        ready = candidate != 2 or len(built) == 2
        assert CANDIDATE_KINDS[kind] == ("shifted" if offset.any() else "ready" if ready else "in_the_air")
        if offset.any():
            assert candidate == 2 and len(built) == 2  # only a ready piece resting on others is slid off
            offsets.append(offset)
    assert (0, True) in seen and (2, True) in seen and (0, False) in seen  # in the air, ready, and a first cube
    # the plank (yaw 90 degrees: its length along world y) slides up to 1.5 half-lengths along it
    offsets = np.array(offsets)
    assert len(offsets) > 5 and np.abs(offsets[:, 1]).max() > 0.07 and np.abs(offsets).max(axis=0)[0] <= 0.0375
    assert not any(build_state(span, np.random.default_rng(s))[2].any() for s in range(30))  # off by default
    row = [Piece("cube", (0.45, y, 0.025)) for y in (-0.06, 0.0, 0.06)]
    assert all(build_state(row, np.random.default_rng(s))[1] in range(3) for s in range(10))
    assert not any(build_state(row, np.random.default_rng(s), shifted=True)[2].any() for s in range(10))  # on the table


@pytest.mark.unit
def test_a_shifted_candidate_never_overlaps_a_piece_already_set():
    # two columns of two cubes side by side, touching: a top cube slid towards the other top one would overlap it
    columns = [Piece("cube", (0.45, y, z)) for z in (0.025, 0.075) for y in (0.0, 0.05)]
    beside = 0
    for seed in range(200):
        built, candidate, offset, _ = build_state(columns, np.random.default_rng(seed), shifted=True)
        if offset.any():
            x, y, z = columns[candidate].position
            moved = Piece("cube", (x + offset[0], y + offset[1], z))
            assert not any(interpenetrate(moved, columns[i]) for i in built)
            beside += (5 - candidate) in built  # the other top cube (2 <-> 3) is set
    assert beside > 3


@pytest.mark.unit
def test_shifted_candidates_are_a_structures_setting_only():
    assert RecorderSettings(scene="structures", shifted_candidates=True).shifted_candidates
    with pytest.raises(ValueError, match="shifted_candidates"):
        RecorderSettings(shifted_candidates=True)


def test_structure_sequences_fall_or_stand_from_rest_and_load_as_a_fall_dataset(tmp_path):
    meta = record_dataset(tmp_path, 24, SETTINGS, workers=1, progress=False)
    assert meta["scene"] == "structures" and len(meta["classes"]) == MAX_PIECES + 1
    shifts = []
    for entry in meta["shards"]:
        with np.load(tmp_path / entry["file"]) as shard:
            assert shard["labels"].shape == (6, 8, 96, 96) and shard["poses"].shape == (6, 8, MAX_PIECES, 7)
            assert (shard["breaker"] == NOT_STRUCK).all() and np.array_equal(shard["labels"], shard["colour_labels"])
            for poses, n, labels in zip(shard["poses"], shard["n_blocks"], shard["labels"]):
                assert np.isnan(poses[:, n:]).all() and not np.isnan(poses[:, :n]).any()
                heights = poses[0, :n, 2]
                assert np.all(np.diff(heights) <= 1e-6)  # class k + 1: the k-th highest piece at rest
                assert labels.max() <= n
                shifts.append(np.linalg.norm(poses[-1, :n, :3] - poses[0, :n, :3], axis=1).max())
    shifts = np.array(shifts)
    assert (shifts > 0.02).any() and (shifts < 0.002).any()  # some fell, some stood still
    again = RecorderSettings(**{**SETTINGS.__dict__})
    assert json.loads((tmp_path / "settings.json").read_text())["scene"] == again.scene
    split = load_split(tmp_path, "train")
    assert split.labels.shape[1:] == (8, 96, 96) and split.n_blocks.max() <= MAX_PIECES
    # Each candidate's kind is stored; a piece set over a missing support always falls, here as in the planner.
    assert split.candidate_kind is not None and set(split.candidate_kind) <= {0, 1}  # not shifted: in the air or ready
    moved = np.linalg.norm(split.poses[:, -1, :, :3] - split.poses[:, 0, :, :3], axis=2)
    in_the_air = split.candidate_kind == CANDIDATE_KINDS.index("in_the_air")
    assert in_the_air.any() and (np.nanmax(moved[in_the_air], axis=1) > 0.004).all()
