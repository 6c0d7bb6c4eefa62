"""The Gymnasium API: checkers, determinism, vector envs, bad input, divergence."""

import subprocess
import sys
import warnings

import gymnasium as gym
import numpy as np
import pytest
from gymnasium.utils.env_checker import check_env as gym_check_env
from stable_baselines3.common.env_checker import check_env as sb3_check_env

from panda_grasp_env import ENV_IDS
from panda_grasp_env.sim.workcell import SPAWN_REGION

ACTION_MODES = ("primitive", "pixel", "ee_delta", "joint")
#: The mode combinations docs/environments.md lists as supported.
OBS_MODES = ("state", "rgbd+segmentation+heightmap+state")
SMALL = {"image_size": (32, 24), "heightmap_resolution": 0.008}  # keep the checks quick
#: One id per task, registered with the task alone: checked in every action and observation mode, and rendered.
TASK_IDS = sorted(env_id for env_id, (kwargs, _) in ENV_IDS.items() if set(kwargs) == {"task"})
#: The other ids: a task's scene or layout variants (clutter, meshes, packed boxes, 2 blocks, a direction).  The
#: action spaces are the env's, the same in every task, so these are checked in both observation modes with one
#: action mode, ee_delta, whose step is one control step (a primitive in a mesh heap takes seconds).
VARIANT_IDS = sorted(set(ENV_IDS) - set(TASK_IDS))
CHECKED_MODES = [
    *((env_id, action, obs) for env_id in TASK_IDS for action in ACTION_MODES for obs in OBS_MODES),
    *((env_id, "ee_delta", obs) for env_id in VARIANT_IDS for obs in OBS_MODES),
]


def make(env_id: str, **kwargs):
    return gym.make(f"panda_grasp_env:{env_id}", **(SMALL | kwargs))


def test_every_task_has_an_id_of_its_own_checked_in_every_mode():
    tasks = {kwargs["task"] for kwargs, _ in ENV_IDS.values()}
    assert {ENV_IDS[env_id][0]["task"] for env_id in TASK_IDS} == tasks and len(TASK_IDS) == len(tasks)
    assert {env_id for env_id, _, _ in CHECKED_MODES} == set(ENV_IDS)


@pytest.mark.parametrize("env_id, action_mode, obs_mode", CHECKED_MODES)
def test_checkers_pass(env_id, action_mode, obs_mode):
    env = make(env_id, action_mode=action_mode, obs_mode=obs_mode)
    with warnings.catch_warnings():
        warnings.simplefilter("error")  # gymnasium's checker must be clean, not just pass
        gym_check_env(env.unwrapped, skip_render_check=True)
    sb3_check_env(env.unwrapped, warn=False)
    env.close()


def test_checkers_pass_for_6dof_grasp_poses():
    # the action space is the env's, whatever the task, scene or observation (each checked above)
    env = make("PandaGrasp-v0", action_mode="grasp_pose", obs_mode=OBS_MODES[1])
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        gym_check_env(env.unwrapped, skip_render_check=True)
    sb3_check_env(env.unwrapped, warn=False)
    env.reset(seed=0)
    with pytest.raises(ValueError, match="quaternion"):
        env.step(np.zeros(7))
    env.close()


@pytest.mark.parametrize("obs_mode", ("rgb", "depth", "segmentation", "heightmap"))
@pytest.mark.parametrize("env_id, action_mode", [("PandaTowerBreak-v0", "primitive"), ("PandaPush-v0", "ee_delta")])
def test_checkers_pass_for_single_image_modalities(env_id, action_mode, obs_mode):
    env = make(env_id, action_mode=action_mode, obs_mode=obs_mode, cameras=("overhead", "wrist"))
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        gym_check_env(env.unwrapped, skip_render_check=True)
    sb3_check_env(env.unwrapped, warn=False)
    env.close()


def test_segmentation_labels_span_their_space_exactly():
    env = make("PandaTowerBuild-v0", obs_mode="segmentation", action_mode="primitive")
    observation, _ = env.reset(seed=0)
    n_objects = len(env.unwrapped.cell.object_ids)
    assert env.observation_space.high.max() == 1 + n_objects  # 0 background, 1 robot, 2 + i object slot i
    assert observation.max() == 1 + n_objects  # the last block is in view of the overhead camera
    env.close()


def test_make_in_a_fresh_interpreter_without_import():
    code = (
        "import gymnasium as gym; env = gym.make('panda_grasp_env:PandaTowerBuild-v0', obs_mode='state', "
        "action_mode='primitive'); o, i = env.reset(seed=0); print(o.shape, env.spec.max_episode_steps)"
    )
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True, timeout=120)
    assert out.stdout.split() == ["(88,)", "30"]


def _rollout(env_id: str, seed: int, n_steps: int, **kwargs) -> list:
    env = make(env_id, **kwargs)
    env.action_space.seed(seed)
    actions = [env.action_space.sample() for _ in range(n_steps)]
    observations = [env.reset(seed=seed)[0]]
    for action in actions:
        observations.append(env.step(action)[0])
    env.close()
    return observations


def _flatten(observations: list) -> list[np.ndarray]:
    return [np.concatenate([np.ravel(v) for v in o.values()]) if isinstance(o, dict) else o for o in observations]


@pytest.mark.parametrize("env_id", sorted(ENV_IDS))
def test_same_seed_same_observations(env_id):
    obs_mode = "state+rgb"
    first = _flatten(_rollout(env_id, 7, 3, obs_mode=obs_mode))
    second = _flatten(_rollout(env_id, 7, 3, obs_mode=obs_mode))
    assert all(np.array_equal(a, b) for a, b in zip(first, second))
    other = _flatten(_rollout(env_id, 8, 0, obs_mode=obs_mode))
    assert not np.array_equal(first[0], other[0])


@pytest.mark.parametrize("env_id", TASK_IDS)  # every id is made in a fresh process: tests/commands/test_lean_install.py
def test_async_vector_env_runs_every_task(env_id):
    # forkserver/spawn: a worker forked from a parent that already owns a GL context hangs forever.
    envs = gym.vector.AsyncVectorEnv([lambda: make(env_id, obs_mode="state+rgb")] * 2, context="forkserver")
    envs.reset(seed=3)
    observations, rewards, terminated, truncated, infos = envs.step(envs.action_space.sample())
    assert rewards.shape == (2,) and "is_success" in infos
    envs.close()


def test_async_vector_env_pixel_mode_with_spawn():
    envs = gym.vector.AsyncVectorEnv(
        [lambda: make("PandaTowerBreak-v0", action_mode="pixel", obs_mode="heightmap")] * 2, context="spawn"
    )
    observations, _ = envs.reset(seed=0)
    assert observations.shape == (2, 56, 56, 4)
    envs.step(envs.action_space.sample())
    envs.close()


@pytest.mark.parametrize("env_id", TASK_IDS)
def test_sb3_subproc_vec_env_runs_every_task(env_id):
    from stable_baselines3.common.env_util import make_vec_env
    from stable_baselines3.common.vec_env import SubprocVecEnv

    envs = make_vec_env(
        f"panda_grasp_env:{env_id}",
        n_envs=2,
        seed=0,
        vec_env_cls=SubprocVecEnv,
        env_kwargs=SMALL | {"obs_mode": "state+rgb"},
        vec_env_kwargs={"start_method": "spawn"},
    )
    envs.reset()
    actions = np.array([envs.action_space.sample() for _ in range(2)])
    _, rewards, _, infos = envs.step(actions)
    assert rewards.shape == (2,) and all("is_success" in i for i in infos)
    envs.close()


# --- bad input ------------------------------------------------------------------------
@pytest.fixture(scope="module")
def push_env():
    env = make("PandaPush-v0")
    env.reset(seed=0)
    yield env
    env.close()


@pytest.mark.unit
@pytest.mark.parametrize(
    "action, message",
    [
        (np.zeros(3), "shape"),
        (np.zeros((4, 1)), "shape"),
        (np.array(["a", "b", "c", "d"]), "numeric"),
        (np.array([0.0, np.nan, 0.0, 0.0]), "NaN or inf at index \\[1\\]"),
        (np.array([0.0, 0.0, np.inf, 0.0]), "NaN or inf at index \\[2\\]"),
    ],
)
def test_bad_actions_raise_naming_the_problem(push_env, action, message):
    with pytest.raises(ValueError, match=message):
        push_env.step(action)


@pytest.mark.unit
def test_out_of_range_actions_are_clipped_and_counted(push_env):
    _, _, _, _, info = push_env.step(np.array([3.0, -2.0, 0.5, 0.0]))
    assert info["actions_clipped"] == 2 and info["actions_clipped_total"] >= 2


@pytest.mark.unit
def test_block_gripper_pushes_with_closed_fingers_and_a_three_value_action():
    env = make("PandaPush-v0", block_gripper=True)
    env.reset(seed=0)
    assert env.action_space.shape == (3,)
    for _ in range(5):
        env.step(np.array([0.0, 0.0, 0.0], dtype=np.float32))
    assert env.unwrapped.cell.robot.finger_gap < 0.005
    with pytest.raises(ValueError, match="block_gripper=True needs action_mode='ee_delta'"):
        make("PandaTowerBreak-v0", action_mode="pixel", block_gripper=True)
    env.close()


@pytest.mark.unit
def test_a_zero_height_action_holds_the_height_while_the_hand_moves_fast():
    env = make("PandaPush-v0", block_gripper=True)
    env.reset(seed=0)
    height = env.unwrapped.cell.robot.ee_position[2]
    for _ in range(15):
        env.step(np.array([1.0, 0.0, 0.0], dtype=np.float32))
    assert abs(env.unwrapped.cell.robot.ee_position[2] - height) < 0.006
    env.close()


@pytest.mark.unit
def test_pixel_mode_publishes_its_action_layout():
    from panda_grasp_env.agents.policies.base import PrimitiveActionWriter

    env = make("PandaTowerBreak-v0", action_mode="pixel", rotations=8)
    _, info = env.reset(seed=0)
    layout = info["action_layout"]
    assert layout["mode"] == "pixel" and int(np.prod(layout["shape"])) == env.action_space.n
    index = env.action_space.n - 1  # the last primitive, rotation, row and column
    primitive, rotation, row, column = np.unravel_index(index, layout["shape"])
    (_, x1), (_, y1), _ = layout["heightmap_bounds"]
    cell = layout["heightmap_resolution"]
    expected = (layout["primitives"][primitive], x1 - (row + 0.5) * cell, y1 - (column + 0.5) * cell)
    assert env.unwrapped.actions.decode(index)[:3] == pytest.approx(expected)
    assert rotation == 7
    # Agents that choose world points write pixel actions too: the cell under the point, the nearest heading.
    write = PrimitiveActionWriter(info, "scripted", ("push",), needs_z=True)
    x, y = env.unwrapped.actions.decode(index)[1:3]
    action = write("push", x + 0.3 * cell, y - 0.3 * cell, 2 * np.pi * 7 / 8 + 0.2)
    assert action.shape == () and int(action) == index and env.action_space.contains(action)
    assert int(write("push", x, y, 2 * np.pi - 0.1)) == np.ravel_multi_index(
        (primitive, 0, row, column), layout["shape"]
    )
    with pytest.raises(ValueError, match="outside the heightmap"):
        write("push", 2.0, 0.0, 0.0)
    env.close()
    factored = make("PandaTowerBreak-v0", action_mode="pixel_factored", rotations=8)
    with pytest.raises(ValueError, match="action_mode='primitive' \\(or 'pixel'\\), not 'pixel_factored'"):
        PrimitiveActionWriter(factored.reset(seed=0)[1], "scripted", ("push",))
    factored.close()


def test_factored_pixel_mode_is_the_pixel_mode_per_dimension():
    pixel = make("PandaTowerBreak-v0", action_mode="pixel", rotations=8)
    factored = make("PandaTowerBreak-v0", action_mode="pixel_factored", rotations=8)
    _, info = factored.reset(seed=0)
    pixel.reset(seed=0)
    shape = info["action_layout"]["shape"]
    assert info["action_layout"]["mode"] == "pixel_factored" and list(factored.action_space.nvec) == shape
    action = np.array([0, 3, 40, 17])
    flat, _ = factored.unwrapped.actions.validate(action)
    assert factored.unwrapped.actions.decode(flat) == pixel.unwrapped.actions.decode(
        int(np.ravel_multi_index(action, shape))
    )
    joint = pixel.unwrapped.action_masks().reshape(shape)
    masks = np.split(factored.unwrapped.action_masks(), np.cumsum(shape)[:-1])
    assert [m.tolist() for m in masks] == [
        joint.any(axis=tuple(a for a in range(4) if a != d)).tolist() for d in range(4)
    ]
    assert masks[2].sum() < shape[2]  # rows far from the tower are masked
    for bad, message in (
        (np.array([0, 3, 40]), "4 integers"),
        (np.array([0, 8, 0, 0]), "outside"),
        (np.array([0.0, 1, 2, 3]), "4 integers"),
    ):
        with pytest.raises(ValueError, match=message):
            factored.step(bad)
    _, _, _, _, info = factored.step(action)
    assert info["primitive"] == "push"
    pixel.close()
    factored.close()


@pytest.mark.unit
def test_bad_pixel_actions_raise():
    env = make("PandaTowerBreak-v0", action_mode="pixel")
    env.reset(seed=0)
    bad = ((-1, "outside"), (env.action_space.n, "outside"), (1.5, "integer"), (True, "integer"))
    shaped = ([5], np.array([5]), (5,), np.array([[5]]))  # a Discrete action is one index, not a sequence of one
    for action, message in (*bad, *((a, "one integer index") for a in shaped)):
        with pytest.raises(ValueError, match=message):
            env.step(action)
    env.close()


@pytest.mark.unit
@pytest.mark.parametrize(
    "kwargs, message",
    [
        ({"obs_mode": "lidar"}, "valid: \\['state', 'proprio', 'rgb'"),
        (
            {"action_mode": "torque"},
            "valid: \\['primitive', 'pixel', 'pixel_factored', 'ee_delta', 'joint', 'grasp_pose'\\]",
        ),
        ({"n_blocks": 9}, "n_blocks"),
        ({"colour": "red"}, "unknown option\\(s\\) \\['colour'\\] for task 'TowerBuild'; valid: \\['n_blocks'"),
        ({"cameras": ("ceiling",)}, "cameras must be distinct names from \\['overhead', 'front', 'wrist'\\]"),
        ({"cameras": 5}, "cameras must be"),
        ({"cameras": ("overhead", "overhead")}, "cameras must be distinct"),
        ({"cameras": ()}, "cameras must be"),
        ({"image_size": (10000, 10000)}, "image_size must be .* from 1 to 2048"),
        ({"image_size": 84}, "image_size"),
        ({"render_size": (4096, 64)}, "render_size must be"),
        ({"heightmap_resolution": 10.0}, "heightmap_resolution=10.0 .* each side must have 16-1024 cells"),
        ({"heightmap_resolution": 1e-4}, "16-1024 cells"),
        ({"heightmap_resolution": 1e-6}, "16-1024 cells"),
        ({"heightmap_resolution": "fine"}, "heightmap_resolution must be a positive number"),
        ({"heightmap_resolution": float("nan")}, "heightmap_resolution must be"),
        ({"heightmap_bounds": ((0.0, 1.0),)}, "heightmap_bounds must be"),
        ({"heightmap_bounds": 3}, "heightmap_bounds must be"),
        ({"scene": "big"}, "scene must be a panda_grasp_env.model.scene.SceneConfig or None, got str"),
        ({"render_mode": "ascii"}, "render_mode"),
        ({"image_size": (0, 10)}, "image_size"),
        ({"image_size": (True, True)}, "image_size"),
        ({"obs_mode": "state+state"}, "obs_mode part 'state' appears twice in 'state\\+state'"),
        ({"obs_mode": "rgbd+rgb"}, "obs_mode part 'rgb' appears twice in 'rgbd\\+rgb'"),
        ({"push_distance": "far"}, "push_distance"),
        ({"start_in_hand": "half"}, "start_in_hand must be a probability"),
        ({"start_in_hand": 1.5}, "start_in_hand must be a probability in \\[0, 1\\], got 1.5"),
        ({"start_in_hand": 0.5}, "start_in_hand needs a low-level action mode .*action_mode='primitive'"),
        ({"start_above_object": -0.1}, "start_above_object must be a probability in \\[0, 1\\]"),
        ({"action_mode": "ee_delta", "start_in_hand": 0.6, "start_above_object": 0.6}, "sum|must be <= 1"),
        (
            {"action_mode": "ee_delta", "start_behind_object": 0.5},
            "start_behind_object needs .*can start behind object",
        ),
    ],
)
@pytest.mark.filterwarnings("ignore:.*render_mode")  # gymnasium warns before our error
def test_bad_options_raise_at_make(kwargs, message):
    with pytest.raises(ValueError, match=message):
        gym.make("panda_grasp_env:PandaTowerBuild-v0", **kwargs)


@pytest.mark.unit
def test_the_env_options_are_read_from_their_one_declaration():
    # EnvOptions' fields are the env options: PandaEnv's signature (names, order, defaults) and the valid names
    # an unknown option's error lists after the task's.
    import dataclasses
    import inspect
    import re

    from panda_grasp_env.env import PandaEnv
    from panda_grasp_env.env_options import ENV_OPTIONS, EnvOptions

    parameters = inspect.signature(PandaEnv).parameters
    assert list(parameters) == ["task", *ENV_OPTIONS, "task_options"]
    assert {name: parameters[name].default for name in ENV_OPTIONS} == {
        field.name: field.default for field in dataclasses.fields(EnvOptions)
    }
    with pytest.raises(ValueError, match=re.escape(f"; env options: {['task', *ENV_OPTIONS]}") + "$"):
        gym.make("panda_grasp_env:PandaTowerBuild-v0", colour="red")


@pytest.mark.unit
def test_reset_options_must_be_a_mapping():
    env = gym.make("panda_grasp_env:PandaTowerBreak-v0")
    with pytest.raises(ValueError, match="reset options must be a dict or None, got int"):
        env.reset(seed=0, options=5)
    with pytest.raises(ValueError, match="unknown reset option\\(s\\) \\['shuffle'\\]; TowerBreak takes \\[\\]"):
        env.reset(seed=0, options={"shuffle": True})
    env.close()


@pytest.mark.unit
@pytest.mark.parametrize(
    "env_id, kwargs",
    [
        ("PandaPush-v0", {"goal_distance": 0.2}),
        ("PandaPush-v0", {"goal_distance": (0.3, 0.1)}),
        ("PandaPush-v0", {"goal_distance": (0.1, float("nan"))}),
        ("PandaTowerBreak-v0", {"impulse_magnitude": "strong"}),
        ("PandaTowerBreak-v0", {"impulse_magnitude": True}),
        ("PandaGrasp-v0", {"n_objects": True}),  # a bool is no count: True was read as 1
        ("PandaGraspClutter-v0", {"max_failures": True}),
        ("PandaTowerBreak-v0", {"k": True}),
        ("PandaPutInBin-v0", {"n_blocks": True}),
        ("PandaTowerBuild-v0", {"block_colours": "grey"}),
        ("PandaTowerBreak-v0", {"block_colours": None}),
        ("PandaBuildAndBreak-v0", {"block_colours": ["uniform"]}),
        ("PandaTowerBreakDirectional-v0", {"block_colours": np.array(["uniform", "distinct"])}),
    ],
)
def test_task_options_of_the_wrong_type_raise_value_errors_naming_them(env_id, kwargs):
    with pytest.raises(ValueError, match=f"task option '{next(iter(kwargs))}' must be"):
        gym.make(f"panda_grasp_env:{env_id}", **kwargs)


@pytest.mark.unit
def test_an_object_thrown_faster_than_anything_here_moves_is_a_physics_error():
    from panda_grasp_env.sim.stepping import MAX_OBJECT_SPEED

    env = make("PandaPush-v0")
    env.reset(seed=0)
    cell = env.unwrapped.cell
    _, _, _, truncated, info = env.step(np.zeros(4))
    assert not truncated and not info["physics_error"]
    body = int(cell.object_ids[0])
    linear = cell.model.jnt_dofadr[cell.model.body_jntadr[body]]
    away = cell.data.xpos[body][:2] - cell.robot.ee_position[:2]  # clear of the hand, which would stop it
    cell.data.qvel[linear : linear + 2] = 2 * MAX_OBJECT_SPEED * away / np.linalg.norm(away)  # as a blow-up throws
    observation, reward, terminated, truncated, info = env.step(np.zeros(4))
    assert truncated and not terminated and info["physics_error"] and reward == -1.0
    env.close()


#: The env options push_grasp_dqn was trained with, written out (not read from its card): the replays below keep
#: the pixel actions it took when it met these faults even if the checkpoint is retrained.
PUSH_GRASP_DQN_OPTIONS = {
    "obs_mode": "heightmap",
    "action_mode": "pixel",
    "heightmap_resolution": 0.004,
    "rotations": 16,
}


def test_a_finger_landing_on_a_packed_cube_does_not_throw_it():
    # The first action push_grasp_dqn takes on this seed: its left finger lands on a 4 cm cube of the packed
    # 3 x 3 grid and presses it into the table until the finger slips off.  MuJoCo 4.0.0's Newton solve on a
    # sparse Jacobian (google-deepmind/mujoco#3767) then threw the cube through the table at 18 m/s.
    env = make("PandaGraspAdversarial-v0", layout="small_cubes_3x3", **PUSH_GRASP_DQN_OPTIONS)
    env.reset(seed=1001300)
    _, _, _, truncated, info = env.step(82720)
    assert info["primitive"] == "grasp" and not info["physics_error"] and not truncated
    env.close()


def test_an_open_hand_does_not_carry_objects_home(soften_finger_limits):
    # push_grasp_dqn's first action on this seed lands its fingers outside two packed long boxes (73 mm
    # across, the open hand's width).  With soft finger limits the boxes forced the fingers 8 mm past their
    # stop; the limits then squeezed the pair in the "open" hand, which lifted both and carried them home.
    lost = {}
    for limits in ("soft", "as built"):
        env = make("PandaGraspAdversarial-v0", layout="long_boxes_2", **PUSH_GRASP_DQN_OPTIONS)
        if limits == "soft":
            soften_finger_limits(env.unwrapped.cell.model)
        env.reset(seed=810602)
        _, _, _, _, info = env.step(57066)
        assert info["primitive"] == "grasp", limits
        lost[limits] = info["objects_lost"]
        env.close()
    assert lost == {"soft": 2, "as built": 0}


@pytest.mark.unit
def test_physics_divergence_truncates_and_reset_recovers():
    env = make("PandaPush-v0")
    env.reset(seed=0)
    env.unwrapped.cell.data.qvel[:] = np.nan
    observation, reward, terminated, truncated, info = env.step(np.zeros(4))
    assert truncated and not terminated and info["physics_error"]
    assert reward == -1.0 and not info["is_success"]  # a sparse goal reward of 0 would read as success
    assert all(np.isfinite(v).all() for v in observation.values())
    _, info = env.reset(seed=1)
    _, _, _, truncated, info = env.step(np.zeros(4))
    assert not truncated and not info["physics_error"]
    env.close()


@pytest.mark.parametrize("env_id", TASK_IDS)
def test_render_check_passes_without_a_display(monkeypatch, env_id):
    # Gymnasium's default check_env builds every advertised render mode; "human" would end the process
    # from C (GLFW) on a server, so without a display an env neither advertises nor accepts it.
    from panda_grasp_env import env as env_module

    monkeypatch.delenv("DISPLAY", raising=False)
    monkeypatch.delenv("WAYLAND_DISPLAY", raising=False)
    with pytest.raises(ValueError, match="needs a display"):
        env_module.PandaEnv(task="TowerBreak", render_mode="human")
    advertised = env_module.advertised_render_modes()
    assert "human" not in advertised and "rgb_array" in advertised
    env = gym.make(f"panda_grasp_env:{env_id}", render_mode="rgb_array", render_size=(64, 48))
    assert env.unwrapped.metadata["render_modes"] == advertised
    gym_check_env(env.unwrapped)  # also builds and renders every advertised mode
    env.close()


@pytest.mark.unit
def test_fuzzed_env_options_raise_value_errors_naming_them():
    # Every env option against values of the wrong type, size or range: a ValueError that names the option,
    # raised before anything is allocated (the process's peak memory stays under 1 GB more).
    import inspect
    import resource

    from panda_grasp_env.env import PandaEnv

    values = [None, "x", 5, -1, 0, 1e9, float("nan"), float("inf"), True, [], {}, (1,), (1, 2, 3), object()]
    five, zero, yes = values[2], values[4], values[8]
    valid = [
        ("rotations", five),
        ("primitive_z", yes),
        ("block_gripper", yes),
        ("randomization", yes),
        ("randomization", values[10]),
    ] + [(f"start_{s}", zero) for s in ("in_hand", "above_object", "behind_object")]
    context = {
        "rotations": {"action_mode": "pixel"},
        "block_gripper": {"task": "Push", "action_mode": "ee_delta"},
        "planner": {"task": "Grasp", "action_mode": "grasp_pose"},
    }
    defaults = {k: p.default for k, p in inspect.signature(PandaEnv.__init__).parameters.items()}
    options = [k for k in defaults if k not in ("self", "task_options")]
    peak = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss  # KiB on Linux
    cases, wrong = 0, []
    for option in options:
        for value in values:
            if (value is None and defaults[option] is None) or any(option == o and value is v for o, v in valid):
                continue
            cases += 1
            try:
                PandaEnv(**{**context.get(option, {}), option: value}).close()
                wrong.append((option, value, "accepted"))
            except ValueError as error:
                if option not in str(error):
                    wrong.append((option, value, str(error)))
            except Exception as error:  # noqa: BLE001  (any other kind is the failure this test looks for)
                wrong.append((option, value, repr(error)))
    assert cases >= 100 and not wrong, wrong
    assert resource.getrusage(resource.RUSAGE_SELF).ru_maxrss - peak < 1024**2


@pytest.mark.unit
def test_the_scene_does_not_repeat_the_draws_of_an_action_space_seeded_alike():
    # Gymnasium seeds ``reset(seed=s)`` and ``action_space.seed(s)`` from the same SeedSequence(s): a layout
    # drawn from the env generator's first draws put the tower where a random agent's first push aimed.
    env = gym.make("panda_grasp_env:PandaTowerBreak-v0")
    repeats = 0
    for seed in range(20):
        env.reset(seed=seed)
        env.action_space.seed(seed)
        first = env.action_space.np_random.random(2)  # what the action space's generator draws first
        tower = env.unwrapped.cell.block_positions()[0, :2]
        spread = (tower - SPAWN_REGION[:, 0]) / (SPAWN_REGION[:, 1] - SPAWN_REGION[:, 0])
        repeats += bool(np.allclose(spread, first, atol=1e-3))  # the blocks settle by micrometres
    env.close()
    assert repeats == 0


@pytest.mark.slow
def test_a_random_agent_seeded_the_usual_way_rarely_breaks_the_tower():
    # With the scene drawn from the generator's first draws, this loop broke 17 of these 40 towers (8 on the
    # first push); drawn from an independent stream, 7 (3 on the first push).  That is the physics, not the
    # streams: on seeds 81000-81119 it broke 2 / 5 / 10 / 11 / 13 of 120 within 1 / 2 / 3 / 4 / 5 pushes -- a
    # random push line crosses the tower about once in 30.  Issue 53's <= 10 % is therefore not met; this
    # bounds what the streams did.
    # Seeds 80000-80039: held out from every selection here.
    env = gym.make("panda_grasp_env:PandaTowerBreak-v0")
    broken = 0
    for seed in range(80_000, 80_040):
        env.reset(seed=seed)
        env.action_space.seed(seed)
        done = False
        while not done:
            _, _, terminated, truncated, info = env.step(env.action_space.sample())
            done = terminated or truncated
        broken += info["is_success"]
    env.close()
    assert broken <= 10  # 25 %: the correlated streams' 42 % is far out


@pytest.mark.unit
@pytest.mark.parametrize("env_id", ["PandaTowerBuild-v0", "PandaPush-v0"])
def test_human_rendering_through_gym_make_without_a_display_is_the_documented_value_error(monkeypatch, env_id):
    """gymnasium.make wraps an env whose class lacks "human" in Gymnasium's pygame HumanRendering, which failed
    only at reset (DependencyNotInstalled: pygame); the env's own refusal runs at make instead."""
    monkeypatch.delenv("DISPLAY", raising=False)
    monkeypatch.delenv("WAYLAND_DISPLAY", raising=False)
    with pytest.raises(ValueError, match="render_mode='human' needs a display .* use 'rgb_array'"):
        gym.make(f"panda_grasp_env:{env_id}", render_mode="human")


@pytest.mark.unit
def test_a_display_whose_server_does_not_answer_is_the_documented_value_error_at_make(monkeypatch, tmp_path):
    """DISPLAY set with no X server behind it: refused at make, where reset used to end the process (GLFW)."""
    monkeypatch.delenv("WAYLAND_DISPLAY", raising=False)
    for display in (":97", f"{tmp_path / 'nothing'}:0", "127.0.0.1:97", "not a display"):
        monkeypatch.setenv("DISPLAY", display)
        with pytest.raises(ValueError, match="needs a display whose server answers"):
            gym.make("panda_grasp_env:PandaTowerBuild-v0", render_mode="human")


@pytest.mark.unit
def test_human_rendering_through_gym_make_with_a_display_is_the_mujoco_viewer(monkeypatch, tmp_path):
    import socket

    from gymnasium.wrappers import HumanRendering

    # A display whose server answers: a listening socket named as DISPLAY's path.  Made, not reset: reset
    # opens the viewer, which needs a real X server.
    server = socket.socket(socket.AF_UNIX, socket.SOCK_STREAM)
    server.bind(str(tmp_path / "X0"))
    server.listen(1)
    monkeypatch.setenv("DISPLAY", f"{tmp_path / 'X0'}:0")
    env = gym.make("panda_grasp_env:PandaTowerBuild-v0", render_mode="human")
    wrappers = []
    layer = env
    while isinstance(layer, gym.Wrapper):
        wrappers.append(type(layer))
        layer = layer.env
    assert HumanRendering not in wrappers and env.unwrapped.render_mode == "human"
    assert "human" in env.unwrapped.metadata["render_modes"]
    env.close()
    server.close()
