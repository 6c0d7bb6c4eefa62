import json

import numpy as np
import pytest

from panda_grasp_env.model.structure_suite import SUITE, as_structure, named_structure, tier_structures
from panda_grasp_env.model.structures import TIERS, Piece, Structure

pytestmark = pytest.mark.unit


def test_the_suite_holds_at_least_24_structures_in_every_tier():
    assert len(SUITE) >= 24
    assert all(tier_structures(tier) for tier in range(1, len(TIERS) + 1))
    assert all(s.tier in range(1, len(TIERS) + 1) for s in SUITE.values())


def test_every_tier_holds_what_its_name_says():
    assert all(not s.prebuilt and not s.scaffold for s in tier_structures(1) + tier_structures(2))
    assert all("plank" in (p.kind for p in s.pieces) for s in tier_structures(3))
    assert all(s.unstable and s.scaffold for s in tier_structures(5))
    assert all(s.prebuilt and s.removed and len(s.goal) < len(s.pieces) for s in tier_structures(6))


@pytest.mark.parametrize("name", sorted(SUITE))
def test_a_structure_reads_back_from_its_json(name):
    structure = SUITE[name]
    assert Structure.of(json.loads(json.dumps(structure.to_dict()))) == structure
    assert as_structure(name) is structure and as_structure(structure.to_dict()) == structure


def test_world_poses_turn_and_shift_the_structure_frame():
    structure = named_structure("row_3")
    positions, yaws = structure.world_poses((0.5, 0.1), np.pi / 2)
    np.testing.assert_allclose(positions[:, 0], 0.5, atol=1e-12)  # the row, along local x, now runs along y
    np.testing.assert_allclose(np.sort(positions[:, 1]), 0.1 + np.array([-0.055, 0.0, 0.055]), atol=1e-12)
    np.testing.assert_allclose(positions[:, 2], 0.025)
    np.testing.assert_allclose(yaws, np.pi / 2)


@pytest.mark.parametrize(
    ("raw", "culprit"),
    [
        ({"name": "x", "pieces": []}, "pieces"),
        ({"name": "x", "pieces": [{"kind": "sphere", "position": [0, 0, 0.025]}]}, "kind"),
        ({"name": "x", "pieces": [{"kind": "cube", "position": [0, 0]}]}, "position"),
        ({"name": "x", "pieces": [{"kind": "cube", "position": [0, 0, float("nan")]}]}, "position"),
        ({"name": "x", "pieces": [{"kind": "cube", "position": [0, 0, 0.025], "colour": "red"}]}, "colour"),
        ({"name": "x", "pieces": [{"kind": "cube", "position": [0, 0, 0.01]}]}, "below the table"),
        ({"name": "x", "pieces": [{"kind": "cube", "position": [0.3, 0, 0.025]}]}, "from the origin"),
        ({"name": "x", "pieces": [{"kind": "cube", "position": [0, 0, 0.025]}] * 2}, "overlap"),
        ({"name": "x", "pieces": [{"kind": "cube", "position": [0, 0, 0.025]}], "removed": [0]}, "prebuilt"),
        ({"name": "x", "pieces": [{"kind": "cube", "position": [0, 0, 0.025]}], "unstable": [[3]]}, "unstable"),
        ({"name": "x", "pieces": [{"kind": "cube", "position": [0, 0, 0.025]}], "tier": 9}, "tier"),
        ({"name": "x", "pieces": [{"kind": "cube", "position": [0, 0, 0.025]}], "height": 1}, "height"),
    ],
)
def test_a_malformed_structure_is_refused_naming_the_culprit(raw, culprit):
    with pytest.raises(ValueError, match=culprit):
        Structure.of(raw)


def test_turned_planks_that_cross_overlap_and_planks_side_by_side_do_not():
    crossing = [Piece("plank", (0, 0, 0.025)), Piece("plank", (0, 0.0, 0.025), np.pi / 2)]
    with pytest.raises(ValueError, match="overlap"):
        Structure("cross", crossing)
    Structure("pair", (Piece("plank", (0, -0.0255, 0.025)), Piece("plank", (0, 0.0255, 0.025))))


def test_an_unknown_name_lists_the_suite():
    with pytest.raises(ValueError, match="tower_4"):
        as_structure("tower_99")
