"""Learning from demonstrations through train.py: behaviour cloning and TQC with demonstrations, on a Minari
dataset recorded by the project's own recorder."""

import gymnasium as gym
import numpy as np
import pytest
import torch

pytest.importorskip("minari")

from panda_grasp_env.agents.learning import demonstrations  # noqa: E402
from panda_grasp_env.agents.learning.config import config_from_dict  # noqa: E402
from panda_grasp_env.agents.learning.imitation import BehaviourCloning, Demonstrations, TQCFromDemonstrations  # noqa: E402
from panda_grasp_env.agents.learning.training import start_run, train  # noqa: E402

DATASET = "panda_grasp_env/stack-expert-v0"


@pytest.fixture(scope="module")
def dataset_path(tmp_path_factory):
    """Four Stack expert episodes (100 steps each) recorded by the recorder."""
    out = tmp_path_factory.mktemp("minari")
    args = demonstrations.parse_args(
        ["--out", str(out), "--agent", "expert", "--task", "Stack", "--episodes", "4", "--seed-start", "40"]
    )
    demonstrations.record(args)
    return str(out)


def spec(path, episodes=4, **extra):
    return {"dataset": DATASET, "episodes": episodes, "path": path, **extra}


@pytest.mark.unit
@pytest.mark.parametrize(
    "value, message",
    [
        (None, "must be a mapping"),
        ({"dataset": DATASET}, "must be a mapping with keys dataset, episodes"),
        ({"dataset": DATASET, "episodes": 0}, "episodes must be an int >= 1"),
        ({"dataset": DATASET, "episodes": 2, "colour": 1}, "must be a mapping"),
        ({"dataset": DATASET, "episodes": 2, "successful_only": "yes"}, "successful_only must be a bool"),
    ],
)
def test_bad_demonstration_specs_name_the_problem(value, message):
    with pytest.raises(ValueError, match=message):
        Demonstrations.of(value)


def test_missing_or_short_datasets_are_refused(dataset_path, tmp_path):
    with pytest.raises(ValueError, match="no Minari dataset"):
        Demonstrations.of(spec(str(tmp_path))).episodes_data()
    with pytest.raises(ValueError, match="holds only"):
        Demonstrations.of(spec(dataset_path, episodes=50)).episodes_data()


@pytest.mark.unit
def test_transitions_match_the_env_spaces(dataset_path):
    env = gym.make("PandaStack-v0")
    observations, actions = Demonstrations.of(spec(dataset_path)).transitions(env.observation_space)
    assert actions.shape == (400, 4) and np.all(np.abs(actions) <= 1)
    assert {k: v.shape for k, v in observations.items()} == {
        k: (400, *s.shape) for k, s in env.observation_space.spaces.items()
    }
    with pytest.raises(ValueError, match="observation 'observation' has shape"):
        Demonstrations.of(spec(dataset_path)).transitions(gym.make("PandaPush-v0").observation_space)
    env.close()


def test_behaviour_cloning_fits_the_demonstrations_and_trains_through_train_py(dataset_path, tmp_path):
    config = config_from_dict(
        {
            "name": "bc_test",
            "env_id": "PandaStack-v0",
            "algo": "bc",
            "total_steps": 400,
            "policy_kwargs": {"net_arch": [64, 64]},
            "algo_kwargs": {"demonstrations": spec(dataset_path), "learning_rate": 0.003, "batch_size": 64},
            "eval_every": 400,
            "eval_episodes": 1,
            "final_eval_episodes": 1,
            "checkpoint_every": 400,
        }
    )
    run = start_run(config, tmp_path)
    final = train(config, run, progress_bar=False)
    assert final["steps"] == 400 and (run / "card.md").read_text().count("minibatches (no environment steps)") == 1
    assert "the first 4 successful episodes of Minari dataset" in (run / "card.md").read_text()
    # The trained actor is closer to the demonstrated actions than an untrained one.
    model = BehaviourCloning.load(run / "latest.zip", device="cpu", demonstrations=spec(dataset_path))
    fresh = BehaviourCloning(
        "MultiInputPolicy",
        gym.make("PandaStack-v0"),
        demonstrations=spec(dataset_path),
        policy_kwargs={"net_arch": [64, 64]},
        seed=1,
    )
    observations, actions = model.demo_batch(400)

    def error(m):
        with torch.no_grad():
            return float(((m.actor(observations, deterministic=True) - actions) ** 2).mean())

    assert error(model) < 0.5 * error(fresh)


@pytest.mark.unit
def test_tqc_with_demonstrations_starts_with_them_in_the_buffer_and_clones_them(dataset_path):
    from stable_baselines3 import HerReplayBuffer
    from stable_baselines3.common.vec_env import DummyVecEnv

    env = DummyVecEnv([lambda: gym.make("PandaStack-v0")] * 2)
    model = TQCFromDemonstrations(
        "MultiInputPolicy",
        env,
        demonstrations=spec(dataset_path),
        bc_weight=1.0,
        replay_buffer_class=HerReplayBuffer,
        buffer_size=2000,
        learning_starts=10,
        batch_size=32,
        policy_kwargs={"net_arch": [32, 32]},
        seed=0,
    )
    model.learn(20)
    assert model.replay_buffer.size() == (400 + 20) // 2  # rows of 2 envs: the 4 demonstrations, the 20 steps
    model.train(gradient_steps=1, batch_size=32)
    assert 0.0 <= model.logger.name_to_value["train/bc_q_filter"] <= 1.0
    # 3 demonstrations on 2 envs: the last row of episodes completes itself with the third one again.
    three = TQCFromDemonstrations(
        "MultiInputPolicy",
        env,
        demonstrations=spec(dataset_path, episodes=3),
        replay_buffer_class=HerReplayBuffer,
        buffer_size=2000,
        learning_starts=10,
    )
    three.learn(2)
    assert three.replay_buffer.size() == 2 * 100 + 1
    stored = three.replay_buffer.observations["observation"]
    assert np.array_equal(stored[100:200, 0], stored[100:200, 1])  # both envs' second episode: the third demo
    assert not np.array_equal(stored[:100, 0], stored[:100, 1])
    env.close()


@pytest.mark.unit
def test_configs_without_demonstrations_are_refused():
    with pytest.raises(ValueError, match="expected a demonstrations entry for bc"):
        config_from_dict({"name": "x", "env_id": "PandaStack-v0", "algo": "bc", "total_steps": 10})
    with pytest.raises(ValueError, match="bc needs algo_kwargs.demonstrations"):
        BehaviourCloning("MultiInputPolicy", gym.make("PandaStack-v0"))
    with pytest.raises(ValueError, match=r"unknown algo_kwargs \['gamma'\] for bc"):
        config_from_dict(
            {
                "name": "x",
                "env_id": "PandaStack-v0",
                "algo": "bc",
                "total_steps": 10,
                "algo_kwargs": {"demonstrations": {"dataset": DATASET, "episodes": 1}, "gamma": 0.9},
            }
        )


def test_a_camera_policy_sees_only_the_observation_keys_it_names():
    from panda_grasp_env.agents.learning.config import observation_transform, training_env

    raw = {
        "name": "x",
        "env_id": "PandaGrasp-v0",
        "algo": "sac",
        "total_steps": 10,
        "env_kwargs": {
            "action_mode": "ee_delta",
            "obs_mode": "proprio+rgb",
            "cameras": ["overhead", "wrist"],
            "image_size": [40, 40],
        },
        "observation_keys": ["proprio", "overhead_rgb", "wrist_rgb", "desired_goal"],
    }
    config = config_from_dict(raw)
    env = training_env(config)
    observation, info = env.reset(seed=0)
    assert sorted(observation) == sorted(raw["observation_keys"]) == sorted(env.observation_space.spaces)
    assert observation["proprio"].shape == (23,)  # the robot alone: no object in what the policy sees
    full = gym.make("PandaGrasp-v0", **raw["env_kwargs"]).reset(seed=0)[0]
    assert sorted(observation_transform(config)(full, {})) == sorted(raw["observation_keys"])
    env.close()
    with pytest.raises(ValueError, match=r"observation_keys \['state'\] are not in"):
        training_env(config_from_dict({**raw, "observation_keys": ["state"]}))
    with pytest.raises(ValueError, match="observation_keys"):
        config_from_dict({**raw, "observation_keys": ["proprio", "proprio"]})


@pytest.mark.unit
def test_image_shift_moves_each_image_within_its_padding_and_leaves_vectors_alone():
    from panda_grasp_env.agents.learning.imitation import _shifted

    images = torch.randint(0, 256, (8, 3, 12, 10), dtype=torch.uint8)
    vector = torch.randn(8, 5)
    out = _shifted({"rgb": images, "proprio": vector}, 2, torch.Generator().manual_seed(0))
    assert out["rgb"].shape == images.shape and out["rgb"].dtype == torch.uint8 and out["proprio"] is vector
    padded = torch.nn.functional.pad(images.float(), (2, 2, 2, 2), mode="replicate").to(torch.uint8)
    for i in range(8):  # each sample is one crop of its own padded image
        crops = [padded[i, :, y : y + 12, x : x + 10] for y in range(5) for x in range(5)]
        assert any(torch.equal(out["rgb"][i], crop) for crop in crops)


#: The push-aware oracle in the pixel mode a heightmap policy acts in (a coarse grid, 4 headings: quick).
PIXEL_OPTIONS = {
    "obs_mode": "heightmap",
    "action_mode": "pixel",
    "heightmap_resolution": 0.008,
    "rotations": 4,
    "layout": "cubes_2x2",
}
PIXEL_DATASET = "panda_grasp_env/packed-oracle-pixel-v0"


@pytest.fixture(scope="module")
def pixel_dataset_path(tmp_path_factory):
    """One episode of the push-aware oracle clearing a packed 2 x 2 grid of cubes in pixel mode."""
    out = tmp_path_factory.mktemp("minari_pixel")
    options = [f"{key}={value}" for key, value in PIXEL_OPTIONS.items()]
    args = demonstrations.parse_args(
        [
            "--out",
            str(out),
            "--agent",
            "oracle",
            "--task",
            "GraspAdversarial",
            "--episodes",
            "1",
            "--seed-start",
            "40",
            "--name",
            PIXEL_DATASET,
            "--task-options",
            *options,
        ]
    )
    demonstrations.record(args)
    return str(out)


def _pixel_dqfd(dataset_path: str, **extra):
    """``heightmap_dqn_demos`` on one recorded oracle episode (``PIXEL_DATASET``), small enough for a test."""
    from panda_grasp_env.agents.learning.heightmap_imitation import HeightmapDQNFromDemonstrations
    from panda_grasp_env.agents.learning.heightmap_observations import EncodedHeightmap
    from panda_grasp_env.agents.learning.heightmap_policy import HeightmapQPolicy

    demos = {"dataset": PIXEL_DATASET, "episodes": 1, "path": dataset_path}
    env = EncodedHeightmap(gym.make("PandaGraspAdversarial-v0", **PIXEL_OPTIONS))
    arguments = {
        "buffer_size": 100,
        "learning_starts": 1,
        "train_freq": 1,
        "batch_size": 4,
        "gamma": 0.5,
        "learning_rate": 3e-3,
        "seed": 0,
        "policy_kwargs": {"rotations": 4, "cell_size": 0.008, "width": 8},
    } | extra
    return HeightmapDQNFromDemonstrations(HeightmapQPolicy, env, demonstrations=demos, **arguments)


def test_heightmap_dqn_with_demonstrations_keeps_them_in_the_buffer_and_ranks_them_first(
    pixel_dataset_path, monkeypatch
):
    from panda_grasp_env.agents.learning.heightmap_imitation import FULL_MARGIN_DISTANCE
    from panda_grasp_env.agents.learning.heightmap_observations import encode_heightmap

    demos = {"dataset": PIXEL_DATASET, "episodes": 1, "path": pixel_dataset_path}
    episode = Demonstrations.of(demos).episodes_data()[0]
    steps = len(episode.actions)
    assert steps >= 4 and np.asarray(episode.actions).dtype.kind in "iu"  # the oracle cleared 4 cubes in pixel mode

    def make(**extra):
        return _pixel_dqfd(pixel_dataset_path, **extra)

    model = make()
    model.learn(2)
    buffer = model.replay_buffer
    assert buffer.size() == steps + 2  # the demonstration first, then the run's own steps
    assert np.array_equal(buffer.observations[0, 0], encode_heightmap(episode.observations[0]))
    assert np.array_equal(buffer.actions[:steps, 0, 0], episode.actions)
    assert np.array_equal(buffer.next_observations[steps - 1, 0], encode_heightmap(episode.observations[-1]))
    assert buffer.dones[steps - 1, 0] == 1 and buffer.rewards[0, 0] == episode.rewards[0]
    model.train(gradient_steps=1, batch_size=4)  # a TD step, then a large-margin step
    assert 0 < model.logger.name_to_value["train/margin_loss"] and "train/margin_met" in model.logger.name_to_value
    # The large-margin loss alone learns to rank the demonstrated actions above every other allowed one.
    observations, actions = model.demo_batch(steps)
    optimiser = torch.optim.Adam(model.q_net.parameters(), lr=3e-3)
    first, _ = model.margin_loss(observations, actions)
    for step in range(400):  # met is judged at one random other heading per call: stop on a call that meets it
        loss, met = model.margin_loss(observations, actions)
        optimiser.zero_grad()
        loss.backward()
        optimiser.step()
        if step >= 150 and met > 0:
            break
    assert loss.item() < 0.7 * first.item() and met > 0
    # The margin is graded with distance: Q falling off from each demonstrated cell faster than the margin
    # grows meets it; falling off slower does not, and the loss is the shortfall.
    q_net = model.q_net
    shape = (q_net.n_primitives, q_net.rotations, q_net.rows, q_net.cols)
    primitive, rotation, row, col = np.unravel_index(actions.numpy(), shape)
    rows, cols = np.meshgrid(np.arange(q_net.rows), np.arange(q_net.cols), indexing="ij")

    def cones(slope, shift=0, every_heading=False):  # Q (per metre from a_E, moved ``shift`` cells) on a_E's map
        def q_maps(observations, rotations):
            maps = torch.full((len(observations), *shape[:1], *shape[2:]), -10.0)
            for i, turned in enumerate(rotations.tolist()):
                if turned == rotation[i] or every_heading:
                    peak = min(row[i] + shift, q_net.rows - 1)
                    metres = PIXEL_OPTIONS["heightmap_resolution"] * np.hypot(rows - peak, cols - col[i])
                    maps[i, primitive[i]] = torch.as_tensor(-slope * metres, dtype=torch.float32)
            return maps

        return q_maps

    steepest_margin = model.margin / FULL_MARGIN_DISTANCE  # per metre; a flat margin would need 0.2 / 2.4 cm
    monkeypatch.setattr(q_net, "q_maps", cones(1.2 * steepest_margin))
    assert model.margin_loss(observations, actions) == (pytest.approx(0.0, abs=1e-6), 1.0)
    # A peak one cell (4 mm) off a_E is still a_E: an upsampled map need not peak on the demonstrated cell.
    monkeypatch.setattr(q_net, "q_maps", cones(3 * steepest_margin, shift=1))
    assert model.margin_loss(observations, actions) == (pytest.approx(0.0, abs=1e-6), 1.0)
    monkeypatch.setattr(q_net, "q_maps", cones(3 * steepest_margin, shift=4))  # 16 mm off: a margin is owed
    assert model.margin_loss(observations, actions)[1] < 1.0
    # The same cone at every heading is owed the whole margin at a quarter turn (4 headings here), unless the
    # action repeats after one (a period of 1 heading: a cube's grasp).
    monkeypatch.setattr(q_net, "q_maps", cones(3 * steepest_margin, every_heading=True))
    loss, met = model.margin_loss(observations, actions)
    assert met == 0.0 and loss.item() == pytest.approx(model.margin)
    quarter = torch.ones(len(actions), dtype=torch.long)
    assert model.margin_loss(observations, actions, quarter) == (pytest.approx(0.0, abs=1e-6), 1.0)
    monkeypatch.setattr(q_net, "q_maps", cones(0.5 * steepest_margin))
    loss, met = model.margin_loss(observations, actions)
    assert met < 1.0 and 0 < loss.item() <= 0.5 * model.margin + 1e-6
    monkeypatch.undo()
    with pytest.raises(
        ValueError, match=f"buffer_size {steps + 1} cannot keep the {steps} demonstrated steps and the run.s 2"
    ):
        make(buffer_size=steps + 1).learn(2)
    with pytest.raises(ValueError, match="margin must be a number >= 0"):
        make(margin=-1)
    # DQfD's pretraining: updates on the demonstrations alone before the first env step, the target network
    # following; once done, never again.
    pretrained = make(pretrain_steps=3, target_update_interval=2, learning_starts=100)  # no update after
    before = [p.clone() for p in pretrained.q_net.parameters()]
    pretrained.learn(1)
    assert pretrained.pretrained_steps == 3 and pretrained.replay_buffer.size() == steps + 1
    assert not all(torch.equal(a, b) for a, b in zip(before, pretrained.q_net.parameters(), strict=True))
    assert all(
        torch.equal(a, b)
        for a, b in zip(pretrained.q_net.parameters(), pretrained.q_net_target.parameters(), strict=True)
    )
    with pytest.raises(ValueError, match="pretrain_steps must be an int >= 0"):
        make(pretrain_steps=1.5)
    with pytest.raises(ValueError, match="expected a demonstrations entry for heightmap_dqn_demos"):
        config_from_dict(
            {"name": "x", "env_id": "PandaGraspAdversarial-v0", "algo": "heightmap_dqn_demos", "total_steps": 10}
        )


def test_cross_entropy_on_the_q_maps_clones_the_demonstrations(pixel_dataset_path, monkeypatch):
    from panda_grasp_env.agents.learning.heightmap_imitation import SAME_ACTION_RADIUS

    model = _pixel_dqfd(pixel_dataset_path, imitation_loss="cross_entropy", temperature=0.1)
    model.learn(2)
    model.train(gradient_steps=1, batch_size=4)  # a TD step, then a cross-entropy step
    assert 0 < model.logger.name_to_value["train/imitation_loss"]
    observations, actions = model.demo_batch(model.demonstration_steps)
    q_net = model.q_net
    shape = (q_net.n_primitives, q_net.rotations, q_net.rows, q_net.cols)
    primitive, rotation, row, col = np.unravel_index(actions.numpy(), shape)
    cell = model.policy.network_args["cell_size"]

    def peaks(shift: int):  # Q 1 at a cell ``shift`` cells from a_E on its map, -1 at every other action
        def q_maps(observations, rotations):
            maps = torch.full((len(observations), shape[0], *shape[2:]), -1.0)
            for i, turned in enumerate(rotations.tolist()):
                if turned == rotation[i]:
                    maps[i, primitive[i], min(row[i] + shift, q_net.rows - 1), col[i]] = 1.0
            return maps

        return q_maps

    inside = int(SAME_ACTION_RADIUS // cell)
    monkeypatch.setattr(q_net, "q_maps", peaks(inside))  # the peak within a_E's disk: a_E is first
    loss, met = model.supervised_loss(observations, actions)
    assert met == 1.0 and 0 < loss.item() < 1.0
    monkeypatch.setattr(q_net, "q_maps", peaks(inside + 2))  # past it: a_E is not
    assert model.supervised_loss(observations, actions)[1] == 0.0
    monkeypatch.undo()
    # Trained on it alone, each demonstrated step's best allowed action on its heading's maps lies in its disk.
    optimiser = torch.optim.Adam(q_net.parameters(), lr=3e-3)
    first, _ = model.supervised_loss(observations, actions)
    for _ in range(300):
        loss, met = model.supervised_loss(observations, actions)
        optimiser.zero_grad()
        loss.backward()
        optimiser.step()
    assert loss.item() < 0.3 * first.item()
    allowed = q_net.allowed(observations).view(len(actions), *shape)[:, :, 0]
    with torch.no_grad():
        maps = q_net.q_maps(observations, torch.as_tensor(rotation)).masked_fill(~allowed, -torch.inf)
    best = np.unravel_index(maps.flatten(1).argmax(1).numpy(), (shape[0], *shape[2:]))
    apart = cell * np.hypot(best[1] - row, best[2] - col)
    assert np.all(best[0] == primitive) and np.all(apart <= SAME_ACTION_RADIUS), apart
    with pytest.raises(ValueError, match="imitation_loss must be one of"):
        _pixel_dqfd(pixel_dataset_path, imitation_loss="hinge")
    with pytest.raises(ValueError, match="temperature must be a number > 0"):
        _pixel_dqfd(pixel_dataset_path, imitation_loss="cross_entropy", temperature=0)
