"""Random training structures: every tier's motifs within the block budget, seeded, and never resembling a
named structure (while a moved copy of any named structure, each piece within the task's tolerance, does)."""

import numpy as np
import pytest

from panda_grasp_env.model.structure_generator import (
    GENERATED_TIERS,
    MOTIFS,
    RESEMBLANCE,
    random_structure,
    resembles,
)
from panda_grasp_env.model.structure_suite import SUITE
from panda_grasp_env.model.structures import Piece


def draws(tier, budget, n=60, seed=0):
    rng = np.random.default_rng(seed)
    return [random_structure(rng, budget, tier) for _ in range(n)]


@pytest.mark.unit
@pytest.mark.parametrize("tier", GENERATED_TIERS)
def test_every_motif_of_a_tier_is_drawn_within_the_budget_and_resembles_no_named_structure(tier):
    drawn = [s for budget in (5, 6, 8) for s in draws(tier, budget)]
    assert all(s.tier == tier for s in drawn)
    assert all(len(s.pieces) <= budget for budget, s in zip([5] * 60 + [6] * 60 + [8] * 60, drawn))
    assert {s.name for s in drawn} == {f"random_{motif.__name__}" for motif, _ in MOTIFS[tier]}
    assert not any(resembles(s.goal, named.goal) for s in drawn for named in SUITE.values())


@pytest.mark.unit
def test_the_same_seed_draws_the_same_structures():
    assert [s.to_dict() for s in draws(2, 6, 10, seed=3)] == [s.to_dict() for s in draws(2, 6, 10, seed=3)]


@pytest.mark.unit
@pytest.mark.parametrize("name", sorted(SUITE))
def test_a_named_structure_moved_with_every_piece_within_the_tolerance_resembles_it(name):
    goal = SUITE[name].goal
    rng = np.random.default_rng(len(name))
    turn = rng.uniform(-np.pi, np.pi)
    c, s = np.cos(turn), np.sin(turn)
    moved = []
    for piece in goal:
        x, y, z = np.array(piece.position) + rng.uniform(-1, 1, 3) * RESEMBLANCE / 2 / np.sqrt(3)
        moved.append(Piece(piece.kind, (c * x - s * y + 0.01, s * x + c * y - 0.02, z), piece.yaw + turn))
    assert resembles(moved, goal)


@pytest.mark.unit
def test_a_budget_no_motif_of_the_tier_fits_and_bad_tiers_are_named():
    with pytest.raises(ValueError, match="resembles no suite structure"):
        random_structure(np.random.default_rng(0), 3, 1)  # the towers of 2 and 3 are the suite's
    for tiers in (0, 5, [], "1", [1, 7], True):
        with pytest.raises(ValueError, match="tiers"):
            random_structure(np.random.default_rng(0), 6, tiers)
    with pytest.raises(ValueError, match="max_pieces"):
        random_structure(np.random.default_rng(0), 9)
