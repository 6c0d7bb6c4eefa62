"""Packed layouts (``Grasp(packed=...)``): they stand as designed, options are checked, and a push frees
what grasps alone cannot take -- planned on the true shapes or on what the camera sees."""

import gymnasium as gym
import numpy as np
import pytest

from panda_grasp_env.agents.evaluation.protocol import PERCEPTION
from panda_grasp_env.agents.policies.grasping import PackedGraspOracle, PlannedGraspAgent
from panda_grasp_env.agents.policies.push_planner import PushPlanner, camera_scene
from panda_grasp_env.tasks.packed_layouts import ADVERSARIAL_LAYOUTS, GAP, random_packed_layout


def test_every_hand_designed_layout_stands_still_with_all_its_objects_in_play():
    for index, (name, layout) in enumerate(ADVERSARIAL_LAYOUTS.items()):
        env = gym.make("panda_grasp_env:PandaGraspAdversarial-v0", obs_mode="state", layout=index)
        cell = env.unwrapped.cell
        _, info = env.reset(seed=index)
        assert info["layout"] == name and info["objects_remaining"] == len(layout), name
        # The unused slots too: parked ones still falling would be blamed on the first primitive as collateral.
        before = cell.object_positions()
        cell.wait(0.5)
        assert np.abs(cell.object_positions() - before).max() < 1e-3, name
        env.close()
    assert len(ADVERSARIAL_LAYOUTS) >= 11


@pytest.mark.unit
def test_same_seed_same_jitter_and_random_layouts_vary():
    env = gym.make("panda_grasp_env:PandaGraspAdversarial-v0", obs_mode="state", layout="cubes_3x3")
    first = env.reset(seed=3)[0].copy()
    assert np.array_equal(env.reset(seed=3)[0], first)
    assert not np.array_equal(env.reset(seed=4)[0], first)
    packed = gym.make("panda_grasp_env:PandaGraspPacked-v0", obs_mode="state")
    counts = {packed.reset(seed=seed)[1]["objects_remaining"] for seed in range(6)}
    assert len(counts) > 1


def test_heap_share_drops_heaps_instead_of_some_packed_layouts():
    """PandaGraspMixed-v0: about half its episodes are heaps of HEAP_OBJECTS, the rest hand-designed layouts; the
    seed decides which, and the slots a layout left spare get the heap's shapes."""
    from panda_grasp_env.model.objects import ObjectShape
    from panda_grasp_env.tasks.grasp_layouts import HEAP_OBJECTS, SPARE_SHAPE

    env = gym.make("panda_grasp_env:PandaGraspMixed-v0", obs_mode="state")
    layouts = [env.reset(seed=seed)[1]["layout"] for seed in range(24)]
    assert 6 <= layouts.count("heap") <= 18 and set(layouts) - {"heap"} <= set(ADVERSARIAL_LAYOUTS)
    seed = layouts.index("heap")
    _, info = env.reset(seed=seed)
    assert info["layout"] == "heap" and len(info["shapes"]) == HEAP_OBJECTS
    assert 0 < info["objects_remaining"] <= HEAP_OBJECTS
    assert env.reset(seed=seed)[1]["layout"] == "heap"
    # After a layout that leaves a slot spare (parked, with the spare shape), a heap gives every slot its shape.
    smallest = min(ADVERSARIAL_LAYOUTS, key=lambda name: len(ADVERSARIAL_LAYOUTS[name]))
    env = gym.make("panda_grasp_env:PandaGraspMixed-v0", obs_mode="state", layout=smallest)
    cell, task = env.unwrapped.cell, env.unwrapped.task
    layouts = [env.reset(seed=seed)[1]["layout"] for seed in range(12)]
    env.reset(seed=layouts.index(smallest))
    spare = cell.object_ids[len(ADVERSARIAL_LAYOUTS[smallest]) :]
    assert len(spare) and all(cell.is_parked(int(body)) for body in spare)
    assert np.allclose(cell.model.geom_size[cell.model.body_geomadr[spare]], ObjectShape(*SPARE_SHAPE).geom_size)
    env.reset(seed=layouts.index("heap"))
    assert len(task.drawn) == HEAP_OBJECTS
    for body, shape in zip(cell.object_ids, task.drawn):
        assert np.allclose(cell.model.geom_size[cell.model.body_geomadr[body]], shape.geom_size)


@pytest.mark.unit
def test_random_packed_grids_stand_gap_apart_at_their_widest_objects():
    """Training grids are packed at the pitch of their widest objects (4 cm cube grids at theirs, not at the
    5 cm cubes'), and grids of 4 cm cubes alone are drawn.  Layout frame, before jitter."""
    rng = np.random.default_rng(0)
    small_cube_grids = 0
    for _ in range(300):
        layout = random_packed_layout(rng)
        if layout[0].kind == "box":
            continue
        widest = max(p.size[0] for p in layout)
        pitch = min(abs(a.x - b.x) for a in layout for b in layout if abs(a.x - b.x) > 1e-9)
        assert pitch == pytest.approx(2 * widest + GAP, abs=1e-9)
        small_cube_grids += all(p.kind == "cube" and p.size[0] == 0.02 for p in layout)
    assert small_cube_grids >= 10


@pytest.mark.unit
@pytest.mark.parametrize(
    ("options", "message"),
    [
        ({"packed": "tight"}, "packed"),
        ({"layout": 0}, "layout"),
        ({"packed": "adversarial", "layout": 99}, "layout"),
        ({"packed": "adversarial", "layout": "pyramid"}, "layout"),
        ({"packed": "adversarial", "n_objects": 3}, "n_objects"),
        ({"packed": "random", "clutter": True}, "clutter"),
        ({"heap_share": 0.5}, "'heap_share' must be"),
        ({"packed": "random", "heap_share": 1.5}, "'heap_share' must be"),
        ({"packed": "random", "heap_share": True}, "'heap_share' must be"),
    ],
)
def test_bad_packed_options_raise_naming_the_option(options, message):
    with pytest.raises(ValueError, match=message):
        gym.make("panda_grasp_env:PandaGrasp-v0", **options)


def cleared(pushes: bool, seed: int) -> tuple[int, int]:
    """(objects grasped, objects in play) of one episode of the oracle on two long boxes side by side."""
    env = gym.make("panda_grasp_env:PandaGraspAdversarial-v0", layout="long_boxes_2", primitive_z=True)
    agent = PackedGraspOracle(env, seed=seed, pushes=pushes)
    observation, info = env.reset(seed=seed)
    agent.reset(observation, info)
    in_play, done = info["objects_remaining"], False
    while not done:
        observation, _, terminated, truncated, info = env.step(agent.act(observation, info))
        done = terminated or truncated
    return info["objects_grasped"], in_play


def test_a_planned_push_frees_boxes_that_grasps_alone_cannot_take():
    # Two long boxes side by side: each is too long to grasp end to end and has no room for a finger beside
    # its neighbour, so the grasp-only oracle takes neither; one push apart and both come off.
    grasped_alone, in_play = cleared(pushes=False, seed=900_000)
    assert in_play == 2 and grasped_alone == 0
    assert cleared(pushes=True, seed=900_000) == (2, 2)


def camera_view(env, seed):
    """The planned agent's noisy overhead view of ``env`` reset with ``seed``, and the reset info."""
    observation, info = env.reset(seed=seed)
    agent = PlannedGraspAgent(noise_seed=seed, seed=seed)
    agent.reset(observation, info)
    agent.candidates(observation)
    return agent, info


@pytest.mark.parametrize("layout", ["cubes_3x3", "long_boxes_5_diagonal", "cube_row_against_boxes"])
def test_the_depth_image_splits_a_packed_layout_into_its_objects(layout):
    """Packed 3 mm apart, with depth noise: one top per object, each centred within 5 mm of the object.  (Objects
    that touch with no gap a pixel wide come out as one: two cubes of cubes_3x3 at seed 5700000 do.)"""
    env = gym.make("panda_grasp_env:PandaGraspAdversarial-v0", layout=layout, primitive_z=True, **PERCEPTION)
    agent, info = camera_view(env, seed=5_700_001)
    cell = env.unwrapped.cell
    scene = camera_scene(agent.view, np.random.default_rng(0))
    true_centres = np.array([cell.data.xpos[b][:2] for b in cell.object_ids if not cell.is_parked(int(b))])
    seen_centres = np.array([points[:, :2].mean(axis=0) for points in scene.objects.values()])
    assert len(seen_centres) == len(true_centres) == info["objects_remaining"]
    distances = np.linalg.norm(true_centres[:, None] - seen_centres[None], axis=2)
    assert np.all(distances.min(axis=1) < 0.005)
    assert sorted(distances.argmin(axis=1)) == list(range(len(seen_centres)))  # each object a top of its own
    env.close()


def test_the_planned_agent_pushes_packed_boxes_apart_from_what_the_camera_sees():
    """Two long boxes side by side: the detector finds no grasp, and the push the planner picks on the camera's
    view opens a gap a finger fits in (judged on the true shapes), loses nothing, and is followed by a grasp."""
    env = gym.make("panda_grasp_env:PandaGraspAdversarial-v0", layout="long_boxes_2", primitive_z=True, **PERCEPTION)
    observation, info = env.reset(seed=5_700_002)
    agent = PlannedGraspAgent(noise_seed=5_700_002, seed=5_700_002)
    agent.reset(observation, info)
    truth, judge = PackedGraspOracle(env), PushPlanner(None)
    assert judge.clearance(truth.scene())[0] == 0
    observation, reward, _, _, info = env.step(agent.act(observation, info))
    assert agent.failures["no_candidate"] == 1 and info["primitive"] == "push"
    assert info["primitive_success"] and reward == 0.5 and info["objects_remaining"] == 2
    assert judge.clearance(truth.scene())[0] >= 1
    agent.act(observation, info)
    assert agent.last is not None  # a grasp, no second push
    env.close()


@pytest.mark.unit
def test_the_push_planner_grasps_and_does_not_push_when_an_object_stands_clear():
    env = gym.make("panda_grasp_env:PandaGrasp-v0", shapes=("cube",), primitive_z=True, **PERCEPTION)
    agent, _ = camera_view(env, seed=5_700_003)
    decision = agent.planner.choose(camera_scene(agent.view, np.random.default_rng(0)), lambda candidate: False)
    assert decision.push_start is None and decision.clear
    cube = env.unwrapped.cell.data.xpos[env.unwrapped.cell.object_ids[0]]
    assert np.linalg.norm(decision.grasp.position[:2] - cube[:2]) < 0.005
    env.close()
