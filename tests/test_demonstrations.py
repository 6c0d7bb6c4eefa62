"""Recording agents as Minari datasets: shards, resume, seeds kept, exact replays, a fresh process reads them."""

import os
import subprocess
import sys

import pytest

minari = pytest.importorskip("minari")

from panda_grasp_env.agents import demonstrations  # noqa: E402


def record(tmp_path, *argv):
    args = demonstrations.parse_args(["--out", str(tmp_path), *argv])
    return demonstrations.record(args)


def test_an_expert_dataset_is_sharded_resumable_and_replays_exactly(tmp_path, monkeypatch, capsys):
    dataset = record(tmp_path, "--agent", "expert", "--task", "Stack", "--episodes", "4", "--shard-size", "2",
                     "--seed-start", "30", "--infos", "is_success")  # fmt: skip
    assert dataset.total_episodes == 4 and dataset.total_steps == 400
    seeds = [m["seed"] for m in dataset.storage.get_episode_metadata(range(4))]
    assert seeds == [30, 31, 32, 33]
    episode = next(dataset.iterate_episodes([0]))
    assert episode.infos["is_success"].shape == (101,)  # reset, then every step
    assert all(demonstrations.replay(dataset, i) for i in range(4))

    monkeypatch.setattr(demonstrations, "record_shard", lambda job: pytest.fail("a finished shard was recorded again"))
    assert record(tmp_path, "--agent", "expert", "--task", "Stack", "--episodes", "4", "--shard-size", "2",
                  "--seed-start", "30").total_episodes == 4  # fmt: skip
    assert "2 of 2 shards already recorded" in capsys.readouterr().out

    read = subprocess.run(
        [sys.executable, "-c", "import minari; print(minari.load_dataset('panda_grasp_env/stack-expert-v0').total_episodes)"],
        env={**os.environ, "MINARI_DATASETS_PATH": str(tmp_path)}, capture_output=True, text=True, check=True,
    )  # fmt: skip
    assert read.stdout.strip() == "4"


def test_image_observations_are_recorded_and_replay_when_lossless(tmp_path):
    dataset = record(tmp_path, "--agent", "random", "--task", "TowerBreak", "--episodes", "1", "--lossless",
                     "--task-options", "obs_mode=rgbd", "image_size=[32,24]", "--infos", "")  # fmt: skip
    episode = next(dataset.iterate_episodes([0]))
    assert episode.observations["rgb"].shape[1:] == (24, 32, 3)
    assert demonstrations.replay(dataset)


@pytest.mark.parametrize(
    "argv", [["--agent", "nobody", "--task", "Stack"], ["--agent", "expert", "--task", "Nothing"],
             ["--agent", "planned", "--task", "Stack"], ["--agent", "expert", "--task", "Stack", "--episodes", "0"],
             ["--agent", "expert", "--task", "Stack", "--name", "no-version"]],
)  # fmt: skip
def test_bad_arguments_stop_with_a_message(argv, capsys):
    with pytest.raises(SystemExit) as stop:
        demonstrations.parse_args(argv)
    assert stop.value.code == 2 and "error:" in capsys.readouterr().err
