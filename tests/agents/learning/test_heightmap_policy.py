"""The heightmap Q-policy (``agents/learning/heightmap_policy.py``): encoded heightmaps, rotations, masks,
exploration."""

import gymnasium as gym
import numpy as np
import pytest
import torch as th
from testkit import blob_observation, tiny_policy

from panda_grasp_env.actions import PixelActions
from panda_grasp_env.agents.learning.heightmap_observations import (
    HEIGHT_RANGE,
    EncodedHeightmap,
    encode_heightmap,
    holding_after,
)
from panda_grasp_env.agents.learning.heightmap_policy import (
    HeightmapDQN,
    HeightmapQPolicy,
    heading_in_image,
    rotation_grid,
    sample,
)
from panda_grasp_env.perception.heightmap import HeightmapGrid
from panda_grasp_env.tasks.tower_break import BREAK_DIRECTIONS


@pytest.mark.unit
@pytest.mark.parametrize("yaw", [0.0, 0.7, 2.0, -2.5])
def test_rotation_brings_a_world_heading_onto_the_image_x_axis(yaw):
    grid = HeightmapGrid(((0.3, 0.7), (-0.2, 0.2), (0.0, 0.3)), 0.01)
    image = th.zeros(1, 1, *grid.shape)
    point = np.array([0.5, 0.0]) + 0.12 * np.array([np.cos(yaw), np.sin(yaw)])
    row, col = grid.world_to_cell(point)
    image[0, 0, row, col] = 1.0
    rotated = sample(image, rotation_grid(heading_in_image(th.tensor([yaw], dtype=th.float32)), image.shape[-1]))
    peak_row, peak_col = np.unravel_index(int(rotated[0, 0].argmax()), grid.shape)
    assert abs(peak_row - 19.5) <= 1 and abs(peak_col - (19.5 + 12)) <= 1


@pytest.mark.unit
def test_encoded_heightmap_keeps_millimetres():
    observation, inside = blob_observation(height=0.123)
    assert observation.shape == (4, 40, 40) and observation.dtype == np.uint8
    assert observation[3][inside][0] * HEIGHT_RANGE / 255 == pytest.approx(0.123, abs=5e-4)
    with pytest.raises(ValueError, match="heightmap"):
        encode_heightmap(np.zeros((40, 40, 3)))


@pytest.mark.unit
def test_directional_command_becomes_heading_planes_the_network_reads():
    env = EncodedHeightmap(
        gym.make(
            "panda_grasp_env:PandaTowerBreakDirectional-v0",
            obs_mode="heightmap",
            action_mode="pixel",
            heightmap_resolution=0.008,
            rotations=4,
        )
    )
    observation, info = env.reset(seed=0)
    assert observation.shape == env.observation_space.shape and observation.shape[0] == 6
    cos_sin = observation[4:, 0, 0] / 127.0 - 1.0
    heading = BREAK_DIRECTIONS[info["direction"]]
    assert cos_sin == pytest.approx([np.cos(heading), np.sin(heading)], abs=0.01)
    assert (observation[4:] == observation[4:, :1, :1]).all()  # constant planes
    env.close()
    th.manual_seed(0)
    space = gym.spaces.Box(0, 255, (6, 40, 40), dtype=np.uint8)
    policy = HeightmapQPolicy(
        space,
        gym.spaces.Discrete(4 * 1600),
        lambda _: 1e-3,
        primitives=("push",),
        rotations=4,
        cell_size=0.01,
        command=True,
    )
    assert policy._get_constructor_parameters()["command"]
    heightmap = np.zeros((40, 40, 4), dtype=np.float32)
    heightmap[10:15, 20:25] = [0.8, 0.2, 0.2, 0.1]
    east, north = (th.as_tensor(encode_heightmap(heightmap, heading=h))[None] for h in (0.0, np.pi / 2))
    assert not th.allclose(policy.q_net(east), policy.q_net(north))  # the command changes the Q-values
    # A command is seen relative to each rotation's heading: rotation 1 (north) under the north command
    # scores what rotation 0 (east) scores under the east command, on a map turned by a quarter.
    turned = np.rot90(heightmap, k=1, axes=(0, 1)).copy()  # rows run along -x, columns along -y
    q_east = policy.q_net(east).view(4, 40, 40)[0]
    q_north = policy.q_net(th.as_tensor(encode_heightmap(turned, heading=np.pi / 2))[None]).view(4, 40, 40)[1]
    assert th.allclose(th.rot90(q_east, 1, (0, 1)), q_north, atol=1e-4)
    with pytest.raises(ValueError, match="6 or 7"):
        HeightmapQPolicy(
            gym.spaces.Box(0, 255, (4, 40, 40), dtype=np.uint8),
            gym.spaces.Discrete(4 * 1600),
            lambda _: 1e-3,
            primitives=("push",),
            rotations=4,
            cell_size=0.01,
            command=True,
        )


@pytest.mark.unit
@pytest.mark.parametrize("refine", [False, True])
def test_policy_only_grasps_on_objects_and_scores_one_rotation_like_all(refine):
    th.manual_seed(0)
    policy = tiny_policy(refine=refine)
    assert (policy.q_net.refine is not None) == refine and policy._get_constructor_parameters()["refine"] == refine
    observation, inside = blob_observation()
    action, _ = policy.predict(observation, deterministic=True)
    p, r, row, col = np.unravel_index(int(action), (2, 4, 40, 40))
    assert p == 0 and inside[row, col]  # a grasp, on the blob
    batch = th.as_tensor(np.stack([observation, blob_observation(centre=(30, 8))[0]]))
    all_q = policy.q_net(batch)
    actions = th.tensor([[int(action)], [3 * 1600 + 30 * 40 + 8]])
    assert th.allclose(policy.q_net.q_at(batch, actions), all_q.gather(1, actions).flatten(), atol=1e-5)
    allowed = policy.q_net.allowed(batch[:1]).reshape(2, 4, 40, 40)
    assert not allowed[1].any()  # push is not used
    assert np.array_equal(allowed[0, 2].numpy(), inside)
    with pytest.raises(ValueError, match="primitives_used"):
        tiny_policy(used=("place",))


@pytest.mark.unit
def test_exploration_samples_only_allowed_actions():
    import gymnasium as gym

    class Blob(gym.Env):
        observation_space = gym.spaces.Box(0, 255, (4, 40, 40), dtype=np.uint8)
        action_space = gym.spaces.Discrete(2 * 4 * 40 * 40)

        def reset(self, seed=None, options=None):
            return blob_observation()[0], {}

        def step(self, action):
            return blob_observation()[0], 0.0, True, False, {}

    small = 100  # transitions: SB3's default million would reserve ~13 GB for 4x40x40 observations
    model = HeightmapDQN(
        HeightmapQPolicy,
        Blob(),
        buffer_size=small,
        policy_kwargs={"primitives": ("grasp", "push"), "rotations": 4, "cell_size": 0.01},
    )
    model.exploration_rate = 1.0
    observation, inside = blob_observation()
    near = np.zeros_like(inside)
    for _ in range(50):
        p, _, row, col = np.unravel_index(int(model.predict(observation)[0]), (2, 4, 40, 40))
        if p == 0:
            assert inside[row, col]
        else:
            near[row, col] = True
    near_cells = round(PixelActions.NEAR / 0.01)  # pushes start at most this many cells (either axis) from the blob
    blob = np.argwhere(inside)
    starts = np.argwhere(near)
    gaps = np.abs(starts[:, None, :] - blob[None, :, :]).max(axis=2).min(axis=1)
    assert len(starts) and gaps.max() <= near_cells
    # The warm-up before learning_starts draws among the allowed actions too (SB3's draws from the whole space).
    warm = HeightmapDQN(
        HeightmapQPolicy, Blob(), buffer_size=small, learning_starts=100, policy_kwargs=model.policy_kwargs, seed=0
    )
    warm.learn(20)
    allowed = warm.q_net.allowed(th.as_tensor(observation[None]))[0].numpy()
    assert warm.replay_buffer.size() == 20 and allowed[warm.replay_buffer.actions[:20, 0, 0]].all()


@pytest.mark.unit
def test_holding_plane_switches_the_masks_between_grasp_and_place():
    import gymnasium as gym

    heightmap = np.zeros((40, 40, 4), dtype=np.float32)
    heightmap[10:15, 10:15] = [0.8, 0.2, 0.2, 0.05]
    assert holding_after({"primitive": "grasp", "primitive_success": True})
    assert not holding_after({"primitive": "place", "primitive_success": True})
    assert not holding_after({"primitive": "grasp", "primitive_success": False}) and not holding_after({})
    holding, empty = encode_heightmap(heightmap, True), encode_heightmap(heightmap, False)
    assert holding.shape == (5, 40, 40) and holding[4].min() == 255 and empty[4].max() == 0
    primitives = ("grasp", "place", "push")
    space = gym.spaces.Box(0, 255, (5, 40, 40), dtype=np.uint8)
    policy = HeightmapQPolicy(
        space,
        gym.spaces.Discrete(3 * 4 * 1600),
        lambda _: 1e-3,
        primitives=primitives,
        rotations=4,
        cell_size=0.01,
        primitives_used=("grasp", "place"),
    )
    allowed = policy.q_net.allowed(th.as_tensor(np.stack([holding, empty]))).reshape(2, 3, 4, 40, 40)
    assert allowed[0, 1].any() and not allowed[0, 0].any()  # holding: place only
    assert allowed[1, 0].any() and not allowed[1, 1].any()  # empty hand: grasp only
    assert not allowed[:, 2].any()  # push unused
    with pytest.raises(ValueError, match="place needs the holding plane"):
        tiny_policy(primitives=primitives, used=("grasp", "place"))


def test_maskable_ppo_cnn_policy_takes_the_encoded_heightmap_as_it_is():
    """SB3's off-the-shelf CnnPolicy on pixel_factored, through the wrapper the docs name: uint8, channels first.
    (benchmarks/cnn_policy.py runs it for 256 steps and prints its parameter count and peak memory.)"""
    from sb3_contrib import MaskablePPO
    from stable_baselines3.common.preprocessing import is_image_space

    from panda_grasp_env.agents.learning.heightmap_observations import EncodedHeightmap

    raw = gym.make(
        "panda_grasp_env:PandaGrasp-v0",
        action_mode="pixel_factored",
        obs_mode="heightmap",
        heightmap_resolution=0.004,
        rotations=4,
    )
    assert not is_image_space(raw.observation_space)  # float32, channels last: CnnPolicy fails on it
    env = EncodedHeightmap(raw)
    assert env.observation_space.shape == (4, 112, 112) and is_image_space(env.observation_space)
    model = MaskablePPO("CnnPolicy", env, n_steps=16, batch_size=8, n_epochs=1, seed=0, device="cpu")
    model.learn(16)
    assert model.num_timesteps == 16
    env.close()


@pytest.mark.unit
def test_a_policy_on_a_wider_grid_keeps_its_weights_and_still_grasps_on_the_object():
    """``on_grid``: the fully convolutional network scores a wider heightmap at the same resolution; a block
    in the part the narrower grid never showed is still where it grasps."""
    th.manual_seed(0)
    policy = tiny_policy()
    assert policy.on_grid(40, 40) is policy
    wide = policy.on_grid(56, 64)
    assert wide.shape == (2, 4, 56, 64) and wide.action_space.n == 2 * 4 * 56 * 64
    assert wide.observation_space.shape == (4, 56, 64)
    assert all(th.equal(a, b) for a, b in zip(policy.state_dict().values(), wide.state_dict().values()))
    observation, inside = blob_observation(rows=56, cols=64, centre=(48, 57))
    p, _, row, col = np.unravel_index(wide.greedy_action(observation), wide.shape)
    assert p == 0 and inside[row, col]
    with pytest.raises(ValueError, match="4 x 4"):
        policy.on_grid(2, 40)
