import mujoco
import numpy as np
import pytest

from panda_grasp_env.model.panda_asset import franka_asset_dir
from panda_grasp_env.model.scene import (
    CAMERA_NAMES,
    CONTACT_SOLIMP,
    CONTACT_SOLREF,
    GRASP_SITE,
    SceneConfig,
    build_model,
)
from panda_grasp_env.sim.workcell import Workcell

pytestmark = pytest.mark.unit  # every test here is fast: the unit tier (python -m pytest -m unit)


def test_panda_is_loaded_from_installed_gymnasium_robotics():
    folder = franka_asset_dir()
    assert "gymnasium_robotics" in str(folder) and (folder / "chain.xml").is_file()


def test_default_scene_contents():
    model = build_model()
    for name in ("block_red", "block_green", "block_blue", "block_yellow"):
        body = model.body(name)
        geom = model.geom(f"{name}_geom")
        np.testing.assert_allclose(model.geom_size[geom.id], [0.025] * 3)
        assert model.body_mass[body.id] == pytest.approx(0.1)
    for camera in CAMERA_NAMES:
        assert model.camera(camera).id >= 0
    model.site(GRASP_SITE)
    assert model.opt.timestep == pytest.approx(0.002)
    assert int(model.opt.cone) == int(mujoco.mjtCone.mjCONE_ELLIPTIC)
    # Gravity compensation on every robot link.
    robot_bodies = [i for i in range(model.nbody) if model.body(i).name.startswith("panda0_")]
    assert all(model.body_gravcomp[i] == 1.0 for i in robot_bodies)


def test_scene_is_configurable():
    config = SceneConfig(n_blocks=2, block_size=0.04, block_mass=0.05, block_friction=(0.8, 0.01, 0.0001))
    model = build_model(config)
    assert config.block_names == ["block_red", "block_green"]
    with pytest.raises(KeyError):
        model.body("block_blue")
    np.testing.assert_allclose(model.geom_size[model.geom("block_green_geom").id], [0.02] * 3)
    assert model.geom_friction[model.geom("block_red_geom").id][0] == pytest.approx(0.8)


@pytest.mark.parametrize(
    "kwargs, culprit",
    [
        ({"n_blocks": -1}, "n_blocks"),
        ({"n_blocks": 0}, "at least one"),
        ({"n_objects": 31}, "n_objects"),
        ({"n_blocks": 9}, "n_blocks"),
        ({"block_size": float("nan")}, "block_size"),
        ({"block_mass": -1.0}, "block_mass"),
        ({"block_size": 0.2}, "block_size"),
        ({"cameras": {"ceiling": None}}, "ceiling"),
        ({"block_friction": (1.0, 0.1)}, "block_friction"),
        ({"noslip_iterations": -1}, "noslip_iterations"),
        ({"sleep": "yes"}, "sleep"),
    ],
)
def test_bad_scene_config_names_the_culprit(kwargs, culprit):
    with pytest.raises(ValueError, match=culprit):
        SceneConfig(**kwargs)


def test_a_scene_given_to_make_keeps_the_action_modes_noslip_pass_unless_it_sets_one():
    # A scene given for another reason (stiff contacts, say) once turned the low-level modes' noslip pass on:
    # scene=SceneConfig() alone then changed the physics (the Push expert failed seed 91023, which it passes).
    import gymnasium as gym

    def noslip(env_id: str, **options) -> int:
        env = gym.make(f"panda_grasp_env:{env_id}", **options)
        iterations = int(env.unwrapped.cell.model.opt.noslip_iterations)
        env.close()
        return iterations

    assert noslip("PandaPush-v0") == noslip("PandaPush-v0", scene=SceneConfig()) == 0
    assert noslip("PandaPush-v0", scene=SceneConfig(noslip_iterations=2)) == 2
    assert noslip("PandaTowerBuild-v0") == noslip("PandaTowerBuild-v0", scene=SceneConfig()) == 3


def test_no_object_is_launched_when_pinched_between_the_finger_capsules():
    # Held-out seed 1100008 of the shipped lift policy: with the asset's torsional friction (0.5 m) on the
    # finger capsules this episode pinched the cube between them and launched it at 8.8 m/s.
    from benchmarks.physics_blowups import PeakTracker
    from panda_grasp_env.agents.policies.learned import Checkpoint, LearnedAgent

    checkpoint = Checkpoint("lift_sac_her")
    env = checkpoint.make_env()
    agent = LearnedAgent("lift_sac_her", env)
    cell = env.unwrapped.cell
    assert np.all(cell.model.geom_friction[cell.model.geom_contype > 0, 1] <= 0.01)  # no half-metre patches
    peak = PeakTracker(cell)
    cell.physics.add_observer(peak)
    observation, info = env.reset(seed=1100008)
    agent.reset(observation, info)
    done = False
    while not done:
        observation, _, terminated, truncated, info = env.step(agent.act(observation, info))
        done = terminated or truncated
    env.close()
    assert peak.speed < 2.0  # m/s, fastest free body; carried objects move at well under 1 m/s


def test_with_stiff_contacts_a_block_pressed_with_100_newtons_sinks_at_most_a_millimetre():
    # MuJoCo's default contact softness lets this 5 cm, 0.1 kg block sink 5.05 mm into the table (a pushed
    # block's leading edge dug in 12 mm); 100 N is about the most a push applies.
    cell = Workcell(SceneConfig(stiff_contacts=True))
    cell.clear()
    block = int(cell.block_ids[0])
    cell.set_body_pose(block, np.array([0.5, 0.0, 0.025]))
    cell.settle(0.2)
    cell.data.xfrc_applied[block, 2] = -100.0
    try:
        cell.wait(1.0)
        bottom = cell.data.xpos[block][2] - 0.025
    finally:
        cell.data.xfrc_applied[block] = 0.0
    assert -0.001 <= bottom <= 0.0005


def test_stiff_contacts_reach_the_world_and_the_pads_fixtures_included():
    def fixtures(spec: mujoco.MjSpec) -> None:
        wall = spec.worldbody.add_geom()
        wall.name, wall.type, wall.size, wall.pos = "wall", mujoco.mjtGeom.mjGEOM_BOX, [0.01, 0.1, 0.05], [0.6, 0, 0.05]

    model = build_model(SceneConfig(fixtures=fixtures, stiff_contacts=True))
    robot = {b for b in range(model.nbody) if model.body(b).name.startswith("panda0_")}
    colliding = [g for g in range(model.ngeom) if model.geom_contype[g] or model.geom_conaffinity[g]]
    stiff = [g for g in colliding if model.geom_bodyid[g] not in robot or model.geom(g).name.endswith("_pad")]
    assert model.geom("wall").id in stiff and model.geom("table").id in stiff
    for geom in stiff:
        assert tuple(model.geom_solref[geom]) == CONTACT_SOLREF, model.geom(geom).name
        assert tuple(model.geom_solimp[geom]) == CONTACT_SOLIMP, model.geom(geom).name
