"""Objects with properties: the Grasp task's ``objects`` specs set shape, size, mass, friction, colour and
resting pose, fixed or drawn per episode, and the physics uses exactly those values."""

import warnings

import gymnasium as gym
import numpy as np
import pytest
from gymnasium.utils.env_checker import check_env

from panda_grasp_env.model.objects import SHAPES, ObjectSpec
from panda_grasp_env.model.scene import CONTACT_SOLREF
from panda_grasp_env.tasks.grasp import OBJECT_PROPERTIES


def make(objects, **options):
    return gym.make("panda_grasp_env:PandaGrasp-v0", objects=objects, **options)


def contact_frictions(cell, geom: int, others: set[int]) -> list[float]:
    """Sliding friction of the active contacts between ``geom`` and any of ``others``."""
    return [
        float(c.friction[0])
        for c in cell.data.contact[: cell.data.ncon]
        if {c.geom1, c.geom2} & {geom} and {c.geom1, c.geom2} & others
    ]


@pytest.mark.unit
def test_mass_and_friction_are_in_the_model_and_in_effect_against_table_and_fingers():
    env = make([{"shape": "cube", "size": (0.025,), "mass": 0.4, "friction": 0.5}])
    _, info = env.reset(seed=0)
    cell = env.unwrapped.cell
    body = int(cell.object_ids[0])
    geom = int(cell.model.body_geomadr[body])
    assert cell.model.body_mass[body] == pytest.approx(0.4)
    assert cell.model.geom_friction[geom][0] == pytest.approx(0.5)
    assert info["objects"][0] | {"rgb": None} == {
        "shape": "cube",
        "size": (0.025,),
        "mass": pytest.approx(0.4),
        "friction": 0.5,
        "rgb": None,
        "lying": False,
    }
    table = {cell.model.geom("table").id}
    assert contact_frictions(cell, geom, table) and set(contact_frictions(cell, geom, table)) == {0.5}

    pads = {cell.model.geom(f"{finger}_pad").id for finger in ("panda0_leftfinger", "panda0_rightfinger")}
    held = []

    def watch(cell):
        held.extend(contact_frictions(cell, geom, pads))

    cell.physics.add_observer(watch)
    position = cell.data.xpos[body].copy()
    yaw = float(np.arctan2(cell.data.xmat[body][3], cell.data.xmat[body][0]))
    _, _, _, _, info = env.step(env.unwrapped.actions.encode("grasp", position[0], position[1], yaw))
    assert info["primitive_success"]  # 0.4 kg held by 20 N pads at friction 0.5
    assert held and set(held) == {0.5}
    assert tuple(cell.model.geom_solref[geom]) == CONTACT_SOLREF


@pytest.mark.unit
def test_a_lying_cylinder_rests_with_its_axis_horizontal():
    env = make([{"shape": "cylinder", "size": (0.02, 0.04), "pose": "lying", "yaw": 0.3}])
    _, info = env.reset(seed=1)
    cell = env.unwrapped.cell
    body = int(cell.object_ids[0])
    axis = cell.data.xmat[body].reshape(3, 3)[:, 2]
    assert abs(axis[2]) < 0.02  # horizontal
    assert cell.data.xpos[body][2] == pytest.approx(0.02, abs=0.002)  # resting on its round side
    assert info["objects"][0]["lying"]
    standing = make([{"shape": "cylinder", "size": (0.02, 0.04), "pose": "standing"}])
    standing.reset(seed=1)
    cell = standing.unwrapped.cell
    assert cell.data.xmat[cell.object_ids[0]].reshape(3, 3)[2, 2] > 0.999


def test_ranges_are_drawn_per_episode_from_the_seed_and_shown_in_info_and_state():
    spec = {
        "shape": ("cube", "sphere"),
        "mass": (0.05, 0.5),
        "friction": (0.3, 0.9),
        "rgb": ((0, 1), 0.5, 0.5),
        "pose": "random",
    }
    env = make([spec], n_objects=2, obs_mode="state")
    observations = env.unwrapped.observations
    assert env.observation_space.shape == (observations.state_size,)
    start = observations.state_size - observations.extra_size  # the properties, then the goal (3)
    assert observations.extra_size == 2 * OBJECT_PROPERTIES + 3
    drawn = []
    for seed in (0, 1, 2, 0):
        observation, info = env.reset(seed=seed)
        cell = env.unwrapped.cell
        properties = observation[start : start + 2 * OBJECT_PROPERTIES].reshape(2, OBJECT_PROPERTIES)
        for row, body, obj in zip(properties, cell.object_ids, info["objects"]):
            geom = cell.model.body_geomadr[body]
            assert 0.05 <= obj["mass"] <= 0.5 and 0.3 <= obj["friction"] <= 0.9
            assert cell.model.body_mass[body] == pytest.approx(obj["mass"])
            assert cell.model.geom_friction[geom][0] == pytest.approx(obj["friction"])
            assert row[: len(SHAPES)].tolist() == [float(obj["shape"] == s) for s in SHAPES]
            assert row[len(SHAPES) + 3 :].tolist() == pytest.approx([obj["mass"], obj["friction"], float(obj["lying"])])
        drawn.append([(o["shape"], o["mass"], o["friction"], o["rgb"]) for o in info["objects"]])
    assert drawn[0] == drawn[3] and drawn[0] != drawn[1] != drawn[2]
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        check_env(env.unwrapped, skip_render_check=True)


@pytest.mark.unit
def test_an_object_without_its_own_friction_keeps_the_scenes_contacts():
    env = make([{"shape": "cube", "friction": 0.5}, {"shape": "cube"}])
    env.reset(seed=0)
    cell = env.unwrapped.cell
    own, plain = (int(cell.model.body_geomadr[b]) for b in cell.object_ids)
    assert cell.model.geom_priority[own] == 2 and cell.model.geom_priority[plain] == 0
    assert cell.model.geom_friction[plain][0] == 1.0
    assert make(None).observation_space.shape == gym.make("panda_grasp_env:PandaGrasp-v0").observation_space.shape


@pytest.mark.unit
def test_the_shorthands_are_one_spec():
    assert ObjectSpec(shape="cube").shape == ("cube",)
    env = gym.make("panda_grasp_env:PandaGrasp-v0", n_objects=3, shapes=("box",))
    assert [s.shape for s in env.unwrapped.task.specs] == [("box",)] * 3


@pytest.mark.unit
@pytest.mark.parametrize(
    "options, culprit",
    [
        ({"objects": [{"mass": -1}]}, r"objects\[0\].*mass"),
        ({"objects": [{"weight": 1}]}, "weight"),
        ({"objects": [{"shape": "cone"}]}, "shape"),
        ({"objects": [{"shape": "cube", "size": (0.02, 0.03)}]}, "size"),
        ({"objects": [{"shape": "cube", "size": {"sphere": [0.02]}}]}, r"size: shape\(s\) \['sphere'\] are not"),
        ({"objects": [{"friction": float("nan")}]}, "friction"),
        ({"objects": [{"pose": "upside"}]}, "pose"),
        ({"objects": [{"rgb": (1, 0)}]}, "rgb"),
        ({"objects": [{"yaw": (1, 0)}]}, "yaw"),
        ({"objects": [{}], "shapes": ("cube",)}, "shorthands"),
        ({"objects": [{}, {}], "n_objects": 3}, "n_objects"),
        ({"objects": []}, "objects"),
        ({"objects": "cube"}, "objects"),
        ({"objects": [5]}, r"objects\[0\]"),
    ],
)
def test_bad_specs_name_the_culprit(options, culprit):
    with pytest.raises(ValueError, match=culprit):
        gym.make("panda_grasp_env:PandaGrasp-v0", **options)
