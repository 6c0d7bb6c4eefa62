"""The rules a heightmap Q-policy can act by (``agents/learning/acting_rules.py``): ``FailureMemory``,
``FaceCentring``, ``InwardPushes`` and ``LackingPlaces``."""

import numpy as np
import pytest
from testkit import blob_observation

from panda_grasp_env.agents.learning.acting_rules import (
    LACKING_INSET,
    FaceCentring,
    FailureMemory,
    InwardPushes,
    LackingPlaces,
)
from panda_grasp_env.agents.learning.heightmap_observations import GOAL_HEIGHT_RANGE, encode_heightmap

pytestmark = pytest.mark.unit  # every test here is fast: the unit tier (python -m pytest -m unit)

SHAPE = (3, 4, 60, 60)  # grasp, place, push; 4 headings; 60 x 60 cells of 4 mm
CELL, BLOCK = 0.004, 0.05


def blocks(*squares: tuple[int, int, int, float]) -> np.ndarray:
    """An encoded heightmap of square top faces (first row, first column, side in cells, height in metres)."""
    heightmap = np.zeros((SHAPE[2], SHAPE[3], 4), dtype=np.float32)
    for row, col, side, height in squares:
        heightmap[max(row, 0) : row + side, max(col, 0) : col + side] = [0.5, 0.5, 0.5, height]
    return encode_heightmap(heightmap)


def action(primitive: int, row: int, col: int, rotation: int = 1) -> int:
    return int(np.ravel_multi_index((primitive, rotation, row, col), SHAPE))


def cell(action_index: int) -> tuple[int, ...]:
    return tuple(int(i) for i in np.unravel_index(action_index, SHAPE))


def centring() -> FaceCentring:
    return FaceCentring(SHAPE, CELL, ("grasp", "place", "push"), BLOCK)


def test_failure_memory_marks_the_failed_heading_and_a_grasps_half_turn_only():
    observation, _ = blob_observation()
    memory = FailureMemory((2, 4, 40, 40), cell_size=0.01, primitives=("grasp", "push"))
    memory.record_failure(np.ravel_multi_index((0, 1, 12, 25), (2, 4, 40, 40)), observation)
    memory.record_failure(np.ravel_multi_index((1, 1, 30, 5), (2, 4, 40, 40)), observation)
    excluded = memory.excluded(observation).reshape(2, 4, 40, 40)
    assert excluded[0, [1, 3], 12, 25].all() and not excluded[0, [0, 2], 12, 25].any()  # the fingers are alike
    assert excluded[1, 1, 30, 5] and not excluded[1, [0, 2, 3], 30, 5].any()  # a push turned round is not
    assert excluded[0, 1, 12 + memory.radius, 25] and not excluded[0, 1, 13 + memory.radius, 25]
    with pytest.raises(ValueError, match="primitive names"):
        FailureMemory((2, 4, 40, 40), cell_size=0.01, primitives=("grasp",))


def test_a_grasp_or_place_goes_to_the_centre_of_the_face_it_chose_at_its_heading():
    scene = blocks((20, 30, 13, BLOCK))  # one block: rows and columns 20-32, centre (26, 36)
    rules = centring()
    assert cell(rules.centred(action(0, 22, 33, rotation=3), scene)) == (0, 3, 26, 36)
    assert cell(rules.centred(action(1, 30, 39), scene)) == (1, 1, 26, 36)
    assert rules.centred(action(2, 22, 33), scene) == action(2, 22, 33)  # a push is left as chosen
    assert rules.centred(action(0, 5, 5), scene) == action(0, 5, 5)  # nothing stands there


def test_a_place_on_the_tower_goes_onto_the_axis_of_its_base():
    rules = centring()
    base = blocks((20, 30, 13, BLOCK))
    rules.centred(action(1, 24, 34), base)  # the first place chose the base: its centre is the axis
    leaning = blocks((20, 30, 13, BLOCK), (22, 32, 13, 3 * BLOCK))  # a third level 2 cells off the base
    assert cell(rules.centred(action(1, 27, 37), leaning)) == (1, 1, 26, 36)
    elsewhere = blocks((20, 30, 13, BLOCK), (40, 5, 13, 2 * BLOCK))  # another tower, 3 cm and more away
    assert cell(rules.centred(action(1, 44, 9), elsewhere)) == (1, 1, 46, 11)


def test_a_face_cut_by_the_heightmaps_edge_is_centred_from_its_inner_edge():
    scene = blocks((20, -5, 13, BLOCK))  # 5 of its 13 columns lie outside: centre (26, 1)
    assert cell(centring().centred(action(0, 25, 4), scene)) == (0, 1, 26, 1)
    corner = blocks((-5, -5, 13, BLOCK))  # cut on two sides: no centre to find
    assert centring().centred(action(0, 3, 3), corner) == action(0, 3, 3)


def test_touching_blocks_are_not_one_face():
    scene = blocks((20, 20, 13, BLOCK), (20, 33, 13, BLOCK))  # two faces side by side, as one
    assert centring().centred(action(0, 26, 31), scene) == action(0, 26, 31)


def test_the_layout_and_sizes_are_checked():
    with pytest.raises(ValueError, match="primitive names"):
        FaceCentring(SHAPE, CELL, ("grasp", "place"), BLOCK)
    with pytest.raises(ValueError, match="cell_size"):
        FaceCentring(SHAPE, 0.06, ("grasp", "place", "push"), BLOCK)


def test_inward_pushes_forbid_toppling_a_tower_away_from_the_middle():
    shape = (2, 4, 40, 40)  # grasp, push; headings +x, +y, -x, -y; 1 cm cells, the middle at (20, 20)
    outward = InwardPushes(shape, 0.01, ("grasp", "push")).excluded().reshape(shape)
    # A push starting at row 5 (15 cm towards +x of the middle), column 20: only heading -x points inwards.
    assert outward[1, [0, 1, 3], 5, 20].all() and not outward[1, 2, 5, 20]
    # Starting at column 35 (15 cm towards -y): only heading +y points inwards.
    assert outward[1, [0, 2, 3], 20, 35].all() and not outward[1, 1, 20, 35]
    # A push meeting a tower in the middle (6.5 cm on) may head anywhere; grasps are never forbidden.
    starts = {0: (26, 20), 1: (20, 26), 2: (13, 20), 3: (20, 13)}  # heading -> (row, col)
    assert not any(outward[1, heading, row, col] for heading, (row, col) in starts.items())
    assert not outward[0].any()
    with pytest.raises(ValueError, match="primitive names"):
        InwardPushes(shape, 0.01, ("push",))


def test_a_base_the_env_gave_is_the_axis_until_a_place_chooses_a_one_block_face():
    from panda_grasp_env.perception.heightmap import HeightmapGrid

    grid = HeightmapGrid(((0.3, 0.54), (-0.12, 0.12), (0.0, 0.3)), CELL)  # 60 x 60 cells of 4 mm
    layout = {"heightmap_bounds": [list(b) for b in grid.bounds], "heightmap_resolution": CELL}
    assert HeightmapGrid.of_layout(layout) == grid and np.allclose(
        grid.cell_position(grid.cell_centres(26, 36)), (26, 36)
    )
    rules = FaceCentring(SHAPE, CELL, ("grasp", "place", "push"), BLOCK, base=(26.0, 36.0))
    leftover = blocks((20, 30, 13, BLOCK), (22, 32, 13, 2 * BLOCK))  # a break left a block on the base, 2 cells off
    assert cell(rules.centred(action(1, 29, 39), leftover)) == (1, 1, 26, 36)  # onto the base, not that block
    assert cell(centring().centred(action(1, 29, 39), leftover)) == (1, 1, 28, 38)  # without it: onto that block


def test_lacking_places_aim_only_inside_what_the_goal_still_lacks():
    shape = (2, 4, 60, 60)  # grasp, place; 4 headings; 4 mm cells
    scene, goal = np.zeros((60, 60)), np.zeros((60, 60))
    goal[10:23, 10:23] = 0.05  # a cube's target on the table, 13 cells (52 mm) square
    goal[30:43, 30:43] = 0.10  # a two-cube stack's footprint, its bottom cube built
    scene[30:43, 30:43] = 0.05
    scene[10:23, 40:53] = 0.05  # a loose cube off the goal

    def encoded(metres: np.ndarray) -> np.ndarray:
        return np.round(metres / GOAL_HEIGHT_RANGE * 255).astype(np.uint8)

    observation = np.stack([np.full((60, 60), 128, np.uint8)] * 3 + [encoded(scene), encoded(goal)])
    rule = LackingPlaces(shape, CELL, ("grasp", "place"), goal_plane=4)
    excluded = rule.excluded(observation).reshape(shape)
    inset = round(LACKING_INSET / CELL)
    allowed = ~excluded[1, 0]
    # Each target's middle, inset by 12 mm from its edge, is open; its rim, the loose cube and the table are not.
    assert allowed[10 + inset : 23 - inset, 10 + inset : 23 - inset].all()
    assert allowed[30 + inset : 43 - inset, 30 + inset : 43 - inset].all()
    assert allowed.sum() == 2 * (13 - 2 * inset) ** 2
    assert not allowed[10:23, 40:53].any() and not allowed[50, 5]
    assert (excluded[1] == excluded[1, :1]).all() and not excluded[0].any()  # every heading alike; grasps never
    # Once the goal stands everywhere, nothing is forbidden: the rule does not choose for the policy.
    built = np.stack([*observation[:3], encoded(goal), encoded(goal)])
    assert not rule.excluded(built).any()
    with pytest.raises(ValueError, match="place primitive"):
        LackingPlaces(shape, CELL, ("grasp", "push"), goal_plane=4)
