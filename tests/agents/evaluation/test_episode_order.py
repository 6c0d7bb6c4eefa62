"""An episode is a function of (agent, task, options, seed) alone: not of the episodes played before it in the
same process, nor of the process.

Seed 65294 of GraspMeshTest (object 994) ended in a physics error after seeds 65290-65293 and succeeded alone:
the kept env's mesh slot still held the hidden parts of the objects before, which changed the collision tree
and the order of contacts, and a light object pinched by the pads was then thrown by a Newton solve cut short
by its line search (``model.scene``).
"""

import json

import pytest

from panda_grasp_env.agents.evaluation.episodes import close_kept_env, run_episode
from panda_grasp_env.agents.evaluation.protocol import EpisodeSpec
from panda_grasp_env.commands import evaluate

pytest.importorskip("pybullet_data", reason="the mesh object set needs the objects extra")


def records(agent, task, seeds):
    """Each seed's result, played in this order in one kept env (as one worker plays a run)."""
    close_kept_env()
    try:
        return {seed: run_episode(EpisodeSpec(agent, task, seed))["result"] for seed in seeds}
    finally:
        close_kept_env()


def test_a_mesh_episode_is_the_same_alone_and_after_other_objects():
    after_others = records("push_grasp_mesh_dqn", "GraspMeshTest", [65290, 65291, 65292, 65293, 65294])
    alone = records("push_grasp_mesh_dqn", "GraspMeshTest", [65294])
    assert after_others[65294] == alone[65294]
    assert not any(result["physics_error"] for result in after_others.values())


@pytest.mark.parametrize(
    ("agent", "task", "seeds"),
    [("random", "GraspMeshClutterTest", [65500, 65501, 65502]), ("oracle", "TowerBuild", [3, 4, 5])],
)
def test_seeds_played_in_either_order_give_the_same_records(agent, task, seeds):
    assert records(agent, task, seeds) == records(agent, task, seeds[::-1])


def test_one_or_two_worker_processes_give_byte_identical_results_on_a_mesh_task(tmp_path):
    # (on a block task: tests/agents/evaluation/test_evaluate.py)
    argv = ["--agents", "random,grasp_mesh_dqn", "--tasks", "GraspMeshTest", "--seeds", "2"]
    outs = [tmp_path / "one", tmp_path / "two"]
    assert evaluate.main([*argv, "--no-video", "--out", str(outs[0])]) == 0
    assert evaluate.main([*argv, "--no-video", "--workers", "2", "--out", str(outs[1])]) == 0
    assert (outs[0] / "results.csv").read_bytes() == (outs[1] / "results.csv").read_bytes()
    episodes = json.loads((outs[0] / "results.json").read_text())["episodes"]
    assert len(episodes) == 4 and {e["spec"]["task"] for e in episodes} == {"GraspMeshTest"}


@pytest.mark.slow
def test_thirty_mesh_heaps_without_a_physics_error_or_a_transit_contact(tmp_path):
    """No physics error in 30 mesh heaps, for the planned agent and a learned one; and transit touches nothing
    there, as on blocks: the hand and its load cross above the heap's measured top, a neighbour lifted with a
    grasped object is the grasp's (work) contact, and so is what a load strikes after slipping from the
    fingers."""
    argv = ["--agents", "planned,grasp_mesh_dqn", "--tasks", "GraspMeshClutterTest", "--seeds", "30"]
    argv += ["--seed-start", "7000000", "--workers", "2", "--no-video", "--out", str(tmp_path)]
    assert evaluate.main(argv) == 0
    episodes = json.loads((tmp_path / "results.json").read_text())["episodes"]
    assert len(episodes) == 60
    assert not any(e["physics_error"] for e in episodes)
    assert [e["spec"] for e in episodes if e["transit_contacts"]] == []


@pytest.mark.slow
@pytest.mark.parametrize(
    ("agent", "task", "seed"),
    [
        # The grasped object slips from the fingers on the way home and falls onto a neighbour.
        ("planned", "GraspMeshClutterTest", 7000022),
        # A neighbour lifted on one lifted with the grasped object swings into the load on the way home.
        ("grasp_clutter_dqn", "GraspMeshClutterTrain", 5000003),
    ],
)
def test_what_a_grasp_carries_or_drops_in_transit_is_not_a_transit_contact(agent, task, seed):
    result = records(agent, task, [seed])[seed]
    assert result["transit_contacts"] == 0 and not result["physics_error"]
