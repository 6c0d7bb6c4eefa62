import json

import numpy as np
import pytest

from panda_grasp_env.model.robot import FINGER_HALF_WIDTH, HAND_BODY_ABOVE_SITE
from panda_grasp_env.model.structure_suite import SUITE, as_structure, named_structure, tier_structures
from panda_grasp_env.model.structures import (
    PROP_FRICTION,
    TIERS,
    Piece,
    Structure,
    footprint_distance,
    slide_outs,
)

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
        (  # a scaffold piece is placed, then taken away: it appears twice
            {
                "name": "x",
                "pieces": [{"kind": "cube", "position": [0, 0, 0.025]}],
                "scaffold": [{"kind": "prop", "position": [0.1, 0, 0.025]}],
                "order": [0, 1],
            },
            "twice",
        ),
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


def test_a_scaffold_is_placed_and_taken_away_in_its_order():
    structure = SUITE["lookout"]
    n = len(structure.pieces)
    assert [i for i in structure.order if i >= n] == [n, n]  # placed, then slid out
    assert structure.order.index(n, structure.order.index(n) + 1) < structure.order.index(3)  # before the far cube


def test_footprint_distance_is_zero_inside_and_euclidean_past_a_corner():
    plank = Piece("plank", (0.0, 0.0, 0.025), np.pi / 2)  # 14 cm along y
    assert footprint_distance((0.01, 0.06), plank) == 0.0
    assert footprint_distance((0.0, 0.1), plank) == pytest.approx(0.03)
    assert footprint_distance((0.055, 0.11), plank) == pytest.approx(0.05)


def test_a_prop_is_a_slider():
    assert Piece("prop", (0.0, 0.0, 0.025)).shape().friction == PROP_FRICTION < 0.5
    assert Piece("cube", (0.0, 0.0, 0.025)).shape().friction is None


def world_pieces(name, heading=0.7):
    structure = SUITE[name]
    every = structure.pieces + structure.scaffold
    centres, yaws = structure.world_poses((0.5, 0.1), heading, every)
    return [Piece(p.kind, tuple(c), float(y)) for p, c, y in zip(every, centres, yaws)]


def test_the_cantilevers_prop_slides_out_sideways_with_the_hand_clear_of_the_plank():
    pillar, plank, *_, prop = world_pieces("cantilever")
    pushes = slide_outs(prop, [plank])
    assert len(pushes) == 2
    axis = np.array([np.cos(plank.yaw), np.sin(plank.yaw)])
    end = np.array(plank.position[:2]) @ axis + 0.07
    for push in pushes:
        stroke = np.array([np.cos(push.heading), np.sin(push.heading)])
        assert abs(stroke @ axis) < 1e-9  # across the plank
        assert np.array(push.start[:2]) @ axis - end > FINGER_HALF_WIDTH  # the fingers past its end
        assert push.start[2] + HAND_BODY_ABOVE_SITE > plank.position[2] + 0.025  # the hand over its top
        assert push.start[2] - 0.015 < prop.position[2] + 0.025 - 0.01  # the fingertips on the prop's face
    assert pushes[0].heading == pytest.approx(pushes[1].heading + np.pi, abs=1e-9) or pushes[
        0
    ].heading == pytest.approx(pushes[1].heading - np.pi, abs=1e-9)


def test_a_prop_all_under_its_plank_cannot_be_slid_out():
    plank = Piece("plank", (0.0, 0.0, 0.075))
    assert not slide_outs(Piece("prop", (0.03, 0.0, 0.025)), [plank])
    assert slide_outs(Piece("prop", (0.07 + 0.025, 0.0, 0.025)), [plank])


def test_the_lookouts_far_cube_stands_in_the_way_out_and_its_cross_plank_does_not():
    pillar, plank, cross, far, prop = world_pieces("lookout")
    pushes = slide_outs(prop, [plank])
    assert all(push.passes_over(far, 0.1) for push in pushes)
    assert not any(push.passes_over(cross, 0.1) or push.passes_over(plank, 0.1) for push in pushes)
