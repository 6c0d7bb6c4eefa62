"""The procedural mesh object set: its fixed split, the scaling rule, mesh geoms that collide as the object's
convex pieces, per-episode objects through reset options, and the benchmarks' sweep of each split."""

import sys

import gymnasium as gym
import mujoco
import numpy as np
import pytest
import yaml
from gymnasium.utils.env_checker import check_env
from testkit import ROOT

pytest.importorskip("pybullet_data", reason="the mesh object set needs the objects extra (the test extra has it)")

from panda_grasp_env.model import meshes  # noqa: E402
from panda_grasp_env.model.meshes import (  # noqa: E402
    EVALUATION_OBJECTS,
    EXCLUDED,
    MAX_MIDDLE_EXTENT,
    MAX_PARTS,
    SPLITS,
    load_mesh_object,
    object_by_seed,
)
from panda_grasp_env.model.objects import ObjectSpec  # noqa: E402
from panda_grasp_env.model.scene import SceneConfig  # noqa: E402
from panda_grasp_env.sim.extents import body_bottom_height  # noqa: E402

TEST_IDS = [900, 905, 990]  # 990: 85 pieces merged into MAX_PARTS geoms


def make(ids, **options):
    return gym.make(
        "panda_grasp_env:PandaGraspMesh-v0", objects=[{"shape": "mesh", "split": "test", "ids": ids}], **options
    )


@pytest.mark.unit
def test_the_split_is_fixed_disjoint_and_complete():
    assert SPLITS["test"] == tuple(range(900, 1000))
    assert not set(SPLITS["train"]) & set(SPLITS["test"])
    assert set(SPLITS["train"]) | set(SPLITS["test"]) | set(EXCLUDED) == set(range(1000))
    assert set(EVALUATION_OBJECTS["train"]) <= set(SPLITS["train"]) and len(EVALUATION_OBJECTS["train"]) == 100
    assert not set(EVALUATION_OBJECTS["train"]) & {295, 297, 602, 824}  # flat: no hand picks them up
    with pytest.raises(ValueError, match="168"):
        meshes.split_of(168)


@pytest.mark.unit
@pytest.mark.parametrize("object_id", TEST_IDS)
def test_an_object_is_scaled_to_the_hand_in_its_principal_frame(object_id):
    mesh = load_mesh_object(object_id)
    points = mesh.vertices
    centred = points - points.mean(axis=0)
    extents = np.sort(np.ptp(centred @ np.linalg.svd(centred, full_matrices=False)[2].T, axis=0))
    assert extents[1] <= MAX_MIDDLE_EXTENT + 1e-9
    assert 1 <= len(mesh.parts) <= MAX_PARTS and mesh.volume > 0
    assert np.all(np.abs(points).max(axis=0) <= mesh.half_extents + 1e-12)
    assert np.all(np.diff(mesh.unit_moments) >= 0)  # principal moments, ascending
    again = load_mesh_object.__wrapped__(object_id)  # deterministic: a fresh load gives the same geometry
    assert all(np.array_equal(a.vertices, b.vertices) for a, b in zip(mesh.parts, again.parts))


@pytest.mark.unit
def test_a_missing_extra_is_named(monkeypatch):
    monkeypatch.setitem(sys.modules, "pybullet_data", None)
    with pytest.raises(ModuleNotFoundError, match=r"panda_grasp_env\[objects\]"):
        meshes.set_root()


@pytest.mark.unit
@pytest.mark.parametrize(
    ("spec", "culprit"),
    [
        ({"shape": "mesh", "split": "test", "ids": [12]}, "not in split 'test'"),
        ({"shape": "mesh", "split": "valid"}, "split"),
        ({"shape": "mesh", "set": "ycb"}, "set"),
        ({"shape": "mesh", "pose": "lying"}, "rests as it falls"),
        ({"shape": "cube", "ids": [3]}, 'shape="mesh"'),
        ({"shape": "mesh", "ids": []}, "ids"),
    ],
)
def test_bad_mesh_specs_name_the_culprit(spec, culprit):
    with pytest.raises(ValueError, match=culprit):
        ObjectSpec.of(spec)


def test_a_mesh_object_falls_onto_a_face_and_collides_through_its_pieces():
    env = make(TEST_IDS, scene=SceneConfig(sleep=False))  # a sleeping object's contacts leave data.contact
    check_env(env.unwrapped, skip_render_check=True)
    _, info = env.reset(seed=3)
    cell = env.unwrapped.cell
    body = int(cell.object_ids[0])
    drawn = info["objects"][0]
    assert drawn["shape"] == "mesh" and drawn["mesh"] in TEST_IDS
    assert cell.model.body_mass[body] == pytest.approx(drawn["mass"])
    assert abs(body_bottom_height(cell.model, cell.data, body)) < 0.003  # resting on the table top
    assert np.linalg.norm(cell.data.cvel[body]) < 0.05
    first = int(cell.model.body_geomadr[body])
    touching = {int(g) for c in cell.data.contact[: cell.data.ncon] for g in (c.geom1, c.geom2)}
    pieces = set(range(first + 1, first + 1 + len(load_mesh_object(drawn["mesh"]).parts)))
    assert touching & pieces and first not in touching


def test_a_resting_mesh_object_sleeps_and_the_hand_still_lifts_it():
    """Mesh scenes turn on MuJoCo's island sleeping (SceneConfig.sleep None); the fingers' contact wakes it."""
    from panda_grasp_env.agents.policies.grasping import OracleGraspAgent

    env = make(TEST_IDS, primitive_z=True)
    observation, info = env.reset(seed=3)
    cell = env.unwrapped.cell
    tree = cell.model.body_treeid[int(cell.object_ids[0])]
    assert cell.model.opt.enableflags & mujoco.mjtEnableBit.mjENBL_SLEEP
    assert cell.data.tree_asleep[tree] >= 0  # settled by the reset drop
    agent = OracleGraspAgent(env)
    agent.reset(observation, info)
    _, _, terminated, _, info = env.step(agent.act(observation, info))
    assert info["primitive"] == "grasp" and info["primitive_success"] and terminated and info["is_success"]
    awake = gym.make("panda_grasp_env:PandaGraspMesh-v0", scene=SceneConfig(sleep=False))
    assert not awake.unwrapped.cell.model.opt.enableflags & mujoco.mjtEnableBit.mjENBL_SLEEP


@pytest.mark.unit
def test_reset_options_choose_the_episodes_object_and_a_primitive_slot_hides_the_mesh():
    env = gym.make(
        "panda_grasp_env:PandaGrasp-v0", objects=[{"shape": ("cube", "mesh"), "split": "test", "ids": [905]}]
    )
    env.reset(seed=0)
    options = {"objects": [{"shape": "mesh", "split": "test", "ids": [905]}]}
    _, first = env.reset(seed=11, options=options)
    _, again = env.reset(seed=11, options=options)
    assert first["objects"] == again["objects"] and first["objects"][0]["mesh"] == 905
    _, cube = env.reset(seed=1, options={"objects": [{"shape": "cube"}]})
    cell = env.unwrapped.cell
    body = int(cell.object_ids[0])
    first_geom = int(cell.model.body_geomadr[body])
    parts = range(first_geom + 1, first_geom + int(cell.model.body_geomnum[body]))
    assert cube["objects"][0]["shape"] == "cube" and cell.model.geom_contype[first_geom] == 1
    assert not any(cell.model.geom_contype[g] or cell.model.geom_conaffinity[g] for g in parts)
    with pytest.raises(ValueError, match=r"\[950\] are not in this env's scene"):
        env.reset(options={"objects": [{"shape": "mesh", "split": "test", "ids": [950]}]})
    with pytest.raises(ValueError, match="unknown reset option"):
        env.reset(options={"layout": 1})


@pytest.mark.unit
def test_the_benchmarks_sweep_each_object_once_per_hundred_seeds():
    for split in ("train", "test"):
        ids = [object_by_seed(split)(seed)["objects"][0]["ids"][0] for seed in range(7000, 7100)]
        assert sorted(ids) == sorted(EVALUATION_OBJECTS[split])


@pytest.mark.unit
def test_every_shipped_config_trains_on_the_train_split():
    """No training config may name the test objects (what ``objects`` specs take: split and ids)."""
    files = [*ROOT.glob("configs/**/*.yaml"), *ROOT.glob("agents/checkpoints/*/config.yaml")]
    assert files
    for path in files:
        for spec in _object_specs(yaml.safe_load(path.read_text())):
            if "mesh" in np.atleast_1d(spec.get("shape", ())):
                parsed = ObjectSpec.of(spec)
                assert parsed.split == "train" and not set(parsed.mesh_ids) & set(SPLITS["test"]), path


def _object_specs(node):
    """Every mapping under an ``objects`` key, anywhere in a parsed YAML tree."""
    if isinstance(node, dict):
        for key, value in node.items():
            if key == "objects" and isinstance(value, list):
                yield from (v for v in value if isinstance(v, dict))
            else:
                yield from _object_specs(value)
    elif isinstance(node, list):
        for value in node:
            yield from _object_specs(value)


def test_the_readmes_single_object_command_runs(tmp_path):
    """The README's one command for a single-object test figure, on 2 of its seeds."""
    import json
    import re
    import shlex

    from panda_grasp_env.commands import evaluate

    block = (ROOT / "README.md").read_text().split("## Unseen objects", 1)[1].split("```bash\n", 1)[1].split("\n```")[0]
    args = shlex.split(block.split("python evaluate.py", 1)[1])
    assert re.search(r"--tasks GraspMeshTest\b", block) and "--seeds" in args
    args[args.index("--seeds") + 1] = "2"
    evaluate.main([*args, "--out", str(tmp_path)])
    metrics = json.loads((tmp_path / "results.json").read_text())["metrics"]["planned/GraspMeshTest"]
    assert metrics["episodes"] == 2 and metrics["first_grasp_success"]["n"] == 2
