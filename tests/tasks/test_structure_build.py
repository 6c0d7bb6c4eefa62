"""StructureBuild: a target structure built, or pieces taken off one, judged with identical pieces matched
optimally; random actions build nothing."""

import numpy as np
import pytest

from panda_grasp_env.agents.policies.structure_builder import build_structure
from panda_grasp_env.env import PandaEnv
from panda_grasp_env.model.structure_suite import SUITE
from panda_grasp_env.primitives.result import PrimitiveResult
from panda_grasp_env.tasks.structure_build import StructureBuild, random_structure

PLACED = PrimitiveResult("place", True, "ok")


@pytest.mark.unit
@pytest.mark.parametrize(
    ("options", "culprit"),
    [
        ({"structure": "tower_99"}, "structure"),
        ({"structure": {"name": "x"}}, "structure"),
        ({"max_pieces": 1}, "max_pieces"),
    ],
)
def test_bad_options_name_the_culprit(options, culprit):
    with pytest.raises(ValueError, match=culprit):
        StructureBuild(**options)


@pytest.mark.unit
def test_random_structures_stay_within_the_budget_and_are_never_the_suites():
    rng = np.random.default_rng(0)
    drawn = [random_structure(rng, budget) for budget in (2, 3, 6, 8) for _ in range(50)]
    assert all(len(s.pieces) <= b for s, b in zip(drawn, [2] * 50 + [3] * 50 + [6] * 50 + [8] * 50))
    suite = {tuple(s.pieces) for s in SUITE.values()}
    assert not any(tuple(s.pieces) in suite for s in drawn)
    assert {s.name for s in drawn} == {"random_tower", "random_row", "random_bridge"}


@pytest.mark.parametrize(("structure", "seed"), [("bridge", 3), ("random", 4), ("pyramid_top", 3)])
def test_the_certificate_builds_what_the_task_calls_a_success(structure, seed):
    env = PandaEnv(task="StructureBuild", structure=structure)
    env.reset(seed=seed)
    task = env.task
    before = task.evaluate(env.cell, PLACED)
    assert not before.success
    slots = env.cell.object_ids[: len(task.structure.pieces)]
    assert build_structure(env.cell, task.structure, task.layout, slots).success
    after = task.evaluate(env.cell, PLACED)
    assert after.success and after.terminated and after.info["placed_fraction"] == 1.0 and after.info["away"]
    env.close()


def test_identical_pieces_count_in_any_target_of_their_kind():
    env = PandaEnv(task="StructureBuild", structure="row_3")
    env.reset(seed=0)
    task, cell = env.task, env.cell
    # The row's cubes stood in reverse order: every target holds a cube, so all three are in place.
    from panda_grasp_env.sim.structure_layout import stand_pieces

    pieces = list(reversed(task.structure.pieces))
    stand_pieces(cell, task.structure, pieces, cell.object_ids[:3], task.layout.origin, task.layout.heading)
    assert task.in_place(cell) == 3
    env.close()


def test_random_actions_build_nothing():
    env = PandaEnv(task="StructureBuild", structure="random")
    for seed in range(3):
        env.reset(seed=seed)
        env.action_space.seed(seed)
        for _ in range(8):
            _, _, terminated, _, info = env.step(env.action_space.sample())
            if terminated:
                break
        assert not info["is_success"]
    env.close()
