"""evaluate.py takes what gym.make takes, and tasks and agents from outside the package (``--import``)."""

import json
import sys
import warnings

import gymnasium as gym
import numpy as np
import pytest
from testkit import ROOT

from panda_grasp_env.agents.evaluation.benchmarks import BENCHMARKS, Benchmark, register_benchmark
from panda_grasp_env.agents.evaluation.episodes import make_env, run_episode
from panda_grasp_env.agents.evaluation.protocol import EpisodeSpec, task_options_from_pairs
from panda_grasp_env.agents.policies import registry
from panda_grasp_env.commands import evaluate
from panda_grasp_env.registration import ENV_IDS, TASKS

SHELF = ROOT / "docs" / "examples" / "shelf_task.py"


@pytest.fixture
def shelf_example():
    """The shelf example imported as ``--import`` does it; its task, id, benchmark and agent unregistered
    afterwards."""
    from panda_grasp_env.agents.evaluation.protocol import import_modules

    import_modules([str(SHELF)])
    yield sys.modules["shelf_task"]
    unregister_shelf()


def unregister_shelf() -> None:
    """Undo what importing the shelf example registered (a default benchmark too: a later test's default
    protocol must not name it)."""
    del TASKS["Shelf"], ENV_IDS["ShelfPlace-v0"], gym.registry["ShelfPlace-v0"]
    del BENCHMARKS["Shelf"], registry.BASELINES["Shelf"], sys.modules["shelf_task"]


OBJECTS = "objects=[{shape: cube, size: [0.025], mass: 0.4}, {shape: sphere, size: [0.02]}]"


def test_task_options_take_a_list_of_object_specs_and_the_records_name_them(tmp_path):
    out = tmp_path / "objects"
    argv = ["--agents", "random", "--tasks", "Grasp", "--seed-list", "3", "--no-video", "--out", str(out)]
    assert evaluate.main([*argv, "--task-options", OBJECTS, "max_episode_steps=3"]) == 0
    (record,) = [json.loads(line) for line in (out / "episodes.jsonl").read_text().splitlines()]
    specs = [{"mass": 0.4, "shape": "cube", "size": [0.025]}, {"shape": "sphere", "size": [0.02]}]
    assert record["result"]["spec"]["options"] == [["max_episode_steps", 3], ["objects", specs]]
    options = {"max_episode_steps": 3, "objects": specs}
    assert record["key"] == f"random/Grasp/3/{json.dumps(options, sort_keys=True)}"
    assert record["result"]["actions"] == 3
    results = json.loads((out / "results.json").read_text())
    assert results["protocol"]["task_options"] == options


@pytest.mark.unit
def test_mapping_options_are_frozen_in_the_spec_and_reach_make_as_given():
    randomization = {"hue_shift": 0.02, "table_rgb": [[0.5, 0.6], [0.5, 0.6], [0.5, 0.6]]}
    spec = EpisodeSpec("random", "PutInBin", 0, (("randomization", randomization),))
    assert hash(spec) == hash(EpisodeSpec("random", "PutInBin", 0, (("randomization", dict(randomization)),)))
    assert spec.make_options == {"randomization": randomization}
    env = make_env(spec)
    try:
        _, info = env.reset(seed=0)
        assert all(0.5 <= v <= 0.6 for v in info["randomization"]["table_rgb"])
    finally:
        env.close()


def test_an_option_the_protocol_sets_too_is_overridden_not_doubled():
    options = task_options_from_pairs(["max_episode_steps=2"], ["BuildAndBreak"])  # the protocol says 30
    assert options == {"max_episode_steps": 2}
    result = run_episode(EpisodeSpec("random", "BuildAndBreak", 0, tuple(options.items())))["result"]
    assert result["actions"] == 2


@pytest.mark.unit
def test_a_protocol_file_takes_mappings_and_imports(tmp_path):
    protocol = tmp_path / "protocol.yaml"
    protocol.write_text(
        f"import: [{SHELF}]\ntasks: [Grasp]\nagents: [random]\n"
        "task_options:\n  objects: [{shape: cube, size: [0.025], mass: 0.4}]\n  randomization: {hue_shift: 0.02}\n"
    )
    try:
        args = evaluate.parse_args(["--config", str(protocol)])
        assert args.imports == [str(SHELF)] and "Shelf" in BENCHMARKS
        assert args.task_options == {
            "objects": [{"shape": "cube", "size": [0.025], "mass": 0.4}],
            "randomization": {"hue_shift": 0.02},
        }
    finally:
        unregister_shelf()


@pytest.mark.unit
def test_a_module_that_does_not_import_is_named(capsys):
    with pytest.raises(SystemExit):
        evaluate.parse_args(["--import", "no_such_lab.tasks"])
    assert "no_such_lab.tasks" in capsys.readouterr().err


@pytest.mark.unit
def test_agents_register_by_decorator_and_a_second_one_for_a_task_is_a_clash():
    assert registry.BASELINES["PutInBin"] is not None and "Lift" in registry.EXPERTS
    with pytest.raises(ValueError, match="PutInBin"):
        registry.register_baseline("PutInBin")(lambda env, seed, oracle: None)
    with pytest.raises(ValueError, match="task names"):
        registry.register_baseline()


@pytest.mark.unit
def test_a_benchmark_needs_a_new_name_and_a_registered_id():
    with pytest.raises(ValueError, match="PutInBin"):
        register_benchmark("PutInBin", Benchmark("PandaPutInBin-v0", quick_seeds=1, full_seeds=1))
    with pytest.raises(ValueError, match="NoSuchId-v0"):
        register_benchmark("Nowhere", Benchmark("NoSuchId-v0", quick_seeds=1, full_seeds=1))
    assert "Nowhere" not in BENCHMARKS


def test_the_shelf_example_runs_through_evaluate_with_spawned_workers(shelf_example, tmp_path):
    out = tmp_path / "shelf"
    argv = ["--import", str(SHELF), "--agents", "planned,random", "--tasks", "Shelf", "--seed-start", "900"]
    assert evaluate.main([*argv, "--seeds", "2", "--workers", "2", "--no-video", "--out", str(out)]) == 0
    metrics = json.loads((out / "results.json").read_text())["metrics"]
    assert metrics["planned/Shelf"]["trial_success"]["successes"] == 2
    assert metrics["random/Shelf"]["trial_success"]["successes"] == 0
    assert metrics["planned/Shelf"]["transit_contacts"] == 0


@pytest.mark.unit
def test_the_shelf_moves_per_seed_and_the_place_on_it_is_aimed_not_a_collision(shelf_example):
    env = gym.make("ShelfPlace-v0")
    try:
        shelves = [env.reset(seed=seed)[1]["shelf_position"] for seed in (1, 2)]
        assert not np.allclose(shelves[0], shelves[1])
        cell = env.unwrapped.cell
        board = cell.model.geom("shelf_board").id
        top = cell.motion.tallest_top()
        assert top == pytest.approx(shelves[1][2]) == pytest.approx(cell.data.geom_xpos[board][2] * 2)
        agent = registry.BASELINES["Shelf"](env, 2, True)  # the oracle: true block poses
        observation, info = env.reset(seed=2)
        agent.reset(observation, info)
        touched = []
        for _ in range(2):
            observation, reward, terminated, _, info = env.step(agent.act(observation, info))
            touched.append((info["primitive"], info["primitive_reason"], info["transit_touched"], info["work_touched"]))
        assert touched[0][:3] == ("grasp", "ok", []) and touched[1][:3] == ("place", "ok", [])
        assert "shelf" in touched[1][3]  # the block set down on the shelf it was aimed at
        assert terminated and reward == 1.0 and info["is_success"]
    finally:
        env.close()


def test_the_shelf_example_passes_both_env_checkers(shelf_example):
    from gymnasium.utils.env_checker import check_env as gym_check_env
    from stable_baselines3.common.env_checker import check_env as sb3_check_env

    env = gym.make("ShelfPlace-v0")
    try:
        with warnings.catch_warnings():
            warnings.simplefilter("error")  # clean, not just passing
            gym_check_env(env.unwrapped, skip_render_check=True)
        sb3_check_env(env.unwrapped, warn=False)
    finally:
        env.close()
