import mujoco
import numpy as np
import pytest

from panda_grasp_env.model.scene import CAMERA_NAMES, GRASP_SITE, SceneConfig, build_model, franka_asset_dir


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
    ],
)
def test_bad_scene_config_names_the_culprit(kwargs, culprit):
    with pytest.raises(ValueError, match=culprit):
        SceneConfig(**kwargs)


def test_no_object_is_launched_when_pinched_between_the_finger_capsules():
    # Held-out seed 1100008 of the shipped lift policy: with the asset's torsional friction (0.5 m) on the
    # finger capsules this episode pinched the cube between them and launched it at 8.8 m/s.
    from benchmarks.physics_blowups import PeakTracker
    from panda_grasp_env.agents.learned import Checkpoint, LearnedAgent

    checkpoint = Checkpoint("lift_sac_her")
    env = checkpoint.make_env()
    agent = LearnedAgent("lift_sac_her", env)
    cell = env.unwrapped.cell
    assert np.all(cell.model.geom_friction[cell.model.geom_contype > 0, 1] <= 0.01)  # no half-metre patches
    peak = PeakTracker(cell)
    cell.step_hooks.append(peak)
    observation, info = env.reset(seed=1100008)
    agent.reset(observation, info)
    done = False
    while not done:
        observation, _, terminated, truncated, info = env.step(agent.act(observation, info))
        done = terminated or truncated
    env.close()
    assert peak.speed < 2.0  # m/s, fastest free body; carried objects move at well under 1 m/s
