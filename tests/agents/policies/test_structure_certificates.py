"""Certificates: the top-down primitives, on true poses, build every named structure from its start layout
(loose pieces, or the structure standing for a removal; a scaffold stood and slid out again) on three seeds.
What admits a structure to the suite: the arm can build it."""

import numpy as np
import pytest

from panda_grasp_env.agents.policies.structure_builder import build_structure
from panda_grasp_env.model.scene import SceneConfig
from panda_grasp_env.model.structure_generator import MAX_PIECES, MOTIFS, random_structure
from panda_grasp_env.model.structure_suite import SUITE
from panda_grasp_env.model.structures import structure_scene
from panda_grasp_env.sim.structure_layout import lay_out_start
from panda_grasp_env.sim.workcell import Workcell

SEEDS = (0, 1, 2)


@pytest.mark.slow  # 24 structures x 3 seeds, up to 16 primitives each: minutes
@pytest.mark.parametrize("name", sorted(SUITE))
def test_the_certificate_builds_the_structure_on_three_seeds(name):
    structure = SUITE[name]
    cell = Workcell(structure_scene(SceneConfig(), structure))
    for seed in SEEDS:
        layout, slots = lay_out_start(cell, structure, np.random.default_rng(seed))
        outcome = build_structure(cell, structure, layout, slots)
        failed = [f"{r.primitive}: {r.reason}" for r in outcome.steps if not r.success]
        assert outcome.success, (seed, failed, outcome.misplaced)


@pytest.mark.parametrize("name", ["tower_2", "bridge", "pyramid_top", "cantilever"])
def test_a_build_from_loose_pieces_a_removal_and_a_scaffold_succeed(name):
    structure = SUITE[name]
    cell = Workcell(structure_scene(SceneConfig(), structure))
    layout, slots = lay_out_start(cell, structure, np.random.default_rng(0))
    assert build_structure(cell, structure, layout, slots).success


def one_of_each_motif(seed):
    """A random training structure of every motif (``structure_generator.MOTIFS``), the first each draws."""
    rng, found = np.random.default_rng(seed), {}
    while len(found) < sum(len(motifs) for motifs in MOTIFS.values()):
        for tier in MOTIFS:
            structure = random_structure(rng, MAX_PIECES, tier)
            found.setdefault(structure.name, structure)
    return found


@pytest.mark.parametrize("seed", [0, pytest.param(1, marks=pytest.mark.slow), pytest.param(2, marks=pytest.mark.slow)])
def test_the_certificate_builds_a_random_training_structure_of_every_motif(seed):
    for name, structure in sorted(one_of_each_motif(seed).items()):
        cell = Workcell(structure_scene(SceneConfig(), structure))
        layout, slots = lay_out_start(cell, structure, np.random.default_rng(seed))
        outcome = build_structure(cell, structure, layout, slots)
        assert outcome.success, (name, structure.to_dict(), [r.reason for r in outcome.steps if not r.success])
