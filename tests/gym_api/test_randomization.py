"""Domain randomisation: drawn from the seed at each reset, within its ranges, undone at the next, and off by
default; the scene a task lays out is the same with it on or off."""

import gymnasium as gym
import numpy as np
import pytest

from panda_grasp_env.randomization import Randomization

pytestmark = pytest.mark.unit  # every test here is fast: the unit tier (python -m pytest -m unit)

IMAGES = {"obs_mode": "rgbd", "cameras": ("overhead", "front"), "image_size": (64, 48)}


def make(**options):
    return gym.make("panda_grasp_env:PandaTowerBuild-v0", **IMAGES, **options)


def test_off_by_default_and_nothing_drawn():
    plain, off = make(), make(randomization=None)
    assert plain.observation_space == off.observation_space
    _, info = plain.reset(seed=5)
    assert "randomization" not in info and plain.unwrapped.randomizer is None


def test_same_seed_same_setting_and_the_same_scene_as_without_it():
    env, plain = make(randomization=True), make()
    first, info = env.reset(seed=5)
    again, info_again = env.reset(seed=5)
    assert info["randomization"] == info_again["randomization"]
    assert all(np.array_equal(first[k], again[k]) for k in first)
    clean, _ = plain.reset(seed=5)
    cell = env.unwrapped.cell
    assert np.allclose(cell.block_positions(), plain.unwrapped.cell.block_positions(), atol=1e-5)
    assert env.reset(seed=6)[1]["randomization"] != info["randomization"]
    assert np.abs(first["overhead_rgb"].astype(int) - clean["overhead_rgb"]).mean() > 1.0  # it looks different


def test_every_part_stays_in_its_range_and_nothing_compounds():
    env, plain = make(randomization=True), make()
    plain.reset(seed=0)
    nominal, model = plain.unwrapped.cell.model, env.unwrapped.cell.model
    cell = env.unwrapped.cell
    table = model.geom("table").id
    for seed in range(8):
        _, info = env.reset(seed=seed)
        ratio = model.body_mass[cell.object_ids] / nominal.body_mass[cell.object_ids]
        assert np.all((0.7 <= ratio) & (ratio <= 1.4))
        assert info["randomization"]["masses"] == pytest.approx(model.body_mass[cell.object_ids].tolist())
        for body, friction in zip(cell.object_ids, info["randomization"]["frictions"]):
            assert 0.6 <= friction <= 1.2 and model.geom_friction[model.body_geomadr[body], 0] == friction
        for name in ("overhead", "front"):
            camera = model.camera(name).id
            assert np.all(np.abs(model.cam_pos[camera] - nominal.cam_pos[camera]) <= 0.01 + 1e-12)
            angle = 2 * np.arccos(min(1.0, abs(float(model.cam_quat[camera] @ nominal.cam_quat[camera]))))
            assert angle <= 0.02 + 1e-9
            # What agents are told is where the camera is now.
            assert np.allclose(info["camera_models"][name].position, cell.data.cam_xpos[camera])
        assert 0.5 <= model.geom_rgba[table, 0] <= 0.72
        intensity = model.light_diffuse[:, 0] / nominal.light_diffuse[:, 0]
        assert np.all((0.7 - 1e-9 <= intensity) & (intensity <= 1.3 + 1e-9))
    # Friction in effect against the table is the drawn one (the object's priority wins the pair).
    geom = model.body_geomadr[cell.object_ids[0]]
    touching = [
        c for c in cell.data.contact[: cell.data.ncon] if geom in (c.geom1, c.geom2) and table in (c.geom1, c.geom2)
    ]
    assert touching and all(c.friction[0] == model.geom_friction[geom, 0] for c in touching)


def test_depth_observations_carry_noise_within_the_space():
    env, quiet = make(randomization={"depth_noise": (2.0, 2.0)}), make(randomization={"depth_noise": (0.0, 0.0)})
    noisy, info = env.reset(seed=1)
    clean, quiet_info = quiet.reset(seed=1)
    assert info["randomization"] | {"depth_noise": 0.0} == quiet_info["randomization"]  # the same, but the noise
    difference = np.abs(noisy["overhead_depth"] - clean["overhead_depth"])
    assert 0.0005 < float(np.median(difference)) < 0.02
    assert np.array_equal(noisy["overhead_rgb"], clean["overhead_rgb"])
    assert env.observation_space.contains(noisy)


@pytest.mark.parametrize(
    "value, culprit",
    [
        ({"light_angle": -1}, "light_angle"),
        ({"mass_scale": (2, 1)}, "mass_scale"),
        ({"hue": 0.1}, "hue"),
        ({"table_rgb": ((0, 1), (0, 1))}, "table_rgb"),
        ({"depth_noise": (0.0, float("nan"))}, "depth_noise"),
        ("yes", "randomization"),
    ],
)
def test_bad_settings_name_the_culprit(value, culprit):
    with pytest.raises(ValueError, match=culprit):
        make(randomization=value)


def test_a_dict_keeps_the_other_defaults():
    assert Randomization.of({"hue_shift": 0.0}) == Randomization(hue_shift=0.0)
    assert Randomization.of(True) == Randomization() and Randomization.of(False) is None
