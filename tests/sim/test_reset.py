import itertools

import numpy as np
import pytest

from panda_grasp_env.model.robot import HOME_QPOS
from panda_grasp_env.primitives.top_down import grasp, place
from panda_grasp_env.sim.stacking import tower_is_built
from panda_grasp_env.sim.workcell import SPAWN_REGION


@pytest.mark.unit
def test_scattered_blocks_do_not_overlap_and_rest_on_the_table(cell):
    for seed in range(5):
        cell.reset(np.random.default_rng(seed), "scattered")
        positions = cell.block_positions()
        np.testing.assert_allclose(positions[:, 2], 0.025, atol=1e-3)
        assert np.all((positions[:, :2] >= SPAWN_REGION[:, 0]) & (positions[:, :2] <= SPAWN_REGION[:, 1]))
        for a, b in itertools.combinations(positions, 2):
            assert np.linalg.norm(a[:2] - b[:2]) > 0.05 * np.sqrt(2)


@pytest.mark.unit
def test_reset_tower_stands_ten_seconds(cell):
    cell.reset(np.random.default_rng(7), "tower")
    base = int(np.argmin(cell.block_positions()[:, 2]))
    assert tower_is_built(cell.block_positions(), base, cell.config.block_size)
    before = cell.block_positions()
    cell.wait(10.0)
    assert np.linalg.norm(cell.block_positions() - before, axis=1).max() < 2e-3


@pytest.mark.unit
def test_reset_clears_robot_and_solver_state(cell):
    cell.reset(np.random.default_rng(0), "scattered")
    position = cell.block_positions()[0]
    grasp(cell, *position, float(cell.block_yaws()[0]))
    cell.reset(np.random.default_rng(0), "scattered")
    np.testing.assert_allclose(cell.robot.joint_positions, HOME_QPOS, atol=2e-3)
    assert cell.robot.body_between_fingers() is None
    assert not cell.robot.gripper_closing
    assert cell.sim_time == 0.0 and cell.physics.steps == 0
    np.testing.assert_allclose(cell.controller.commanded_qpos, cell.robot.joint_positions, atol=1e-4)


def _run_sequence(cell, seed: int) -> np.ndarray:
    cell.reset(np.random.default_rng(seed), "scattered")
    positions, yaws = cell.block_positions(), cell.block_yaws()
    grasp(cell, *positions[1], float(yaws[1]))
    place(cell, positions[0][0], positions[0][1], 0.05, float(yaws[0]))
    return np.concatenate([cell.data.qpos.copy(), cell.data.qvel.copy()])


def test_same_seed_gives_bit_identical_state(cell):
    first = _run_sequence(cell, 11)
    _run_sequence(cell, 12)  # something different in between
    second = _run_sequence(cell, 11)
    assert np.array_equal(first, second)


@pytest.mark.unit
def test_settling_replays_its_ik_solves_bit_for_bit(monkeypatch):
    """Every reset holds the arm at home while the scene settles; those IK solves depend on nothing but the
    synced configuration, so a later reset replays them (no QP) and ends in exactly the state a fresh
    controller reaches."""
    import mink

    from panda_grasp_env.control import controller
    from panda_grasp_env.sim.workcell import Workcell

    solves = []
    solve_ik = mink.solve_ik
    monkeypatch.setattr(controller.mink, "solve_ik", lambda *a, **k: solves.append(1) or solve_ik(*a, **k))

    def settled(cell: Workcell, seed: int) -> np.ndarray:
        cell.reset(np.random.default_rng(seed), "tower")
        return np.concatenate([cell.data.qpos, cell.data.qvel, cell.controller.configuration.q])

    warm = Workcell()
    settled(warm, 1)
    solves.clear()
    replayed = settled(warm, 2)
    assert not solves  # every solve of the hold came from the memo
    fresh = settled(Workcell(), 2)
    assert solves  # a new controller solves them
    assert np.array_equal(replayed, fresh)
