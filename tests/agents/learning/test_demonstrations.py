"""Recording agents as Minari datasets: shards, resume, seeds kept, exact replays, a fresh process reads them."""

import os
import subprocess
import sys

import pytest

minari = pytest.importorskip("minari")

from panda_grasp_env.agents.learning import demonstrations  # noqa: E402


def record(tmp_path, *argv):
    args = demonstrations.parse_args(["--out", str(tmp_path), *argv])
    return demonstrations.record(args)


def test_an_expert_dataset_is_sharded_resumable_and_replays_exactly(tmp_path, monkeypatch, capsys):
    dataset = record(
        tmp_path,
        "--agent",
        "expert",
        "--task",
        "Stack",
        "--episodes",
        "4",
        "--shard-size",
        "2",
        "--seed-start",
        "30",
        "--infos",
        "is_success",
    )
    assert dataset.total_episodes == 4 and dataset.total_steps == 400
    seeds = [m["seed"] for m in dataset.storage.get_episode_metadata(range(4))]
    assert seeds == [30, 31, 32, 33]
    episode = next(dataset.iterate_episodes([0]))
    assert episode.infos["is_success"].shape == (101,)  # reset, then every step
    assert all(demonstrations.replay(dataset, i) for i in range(4))

    monkeypatch.setattr(demonstrations, "record_shard", lambda job: pytest.fail("a finished shard was recorded again"))
    assert (
        record(
            tmp_path,
            "--agent",
            "expert",
            "--task",
            "Stack",
            "--episodes",
            "4",
            "--shard-size",
            "2",
            "--seed-start",
            "30",
        ).total_episodes
        == 4
    )
    assert "2 of 2 shards already recorded" in capsys.readouterr().out

    read = subprocess.run(
        [
            sys.executable,
            "-c",
            "import minari; print(minari.load_dataset('panda_grasp_env/stack-expert-v0').total_episodes)",
        ],
        env={**os.environ, "MINARI_DATASETS_PATH": str(tmp_path)},
        capture_output=True,
        text=True,
        check=True,
    )
    assert read.stdout.strip() == "4"


def test_image_observations_are_recorded_and_replay_when_lossless(tmp_path):
    dataset = record(
        tmp_path,
        "--agent",
        "random",
        "--task",
        "TowerBreak",
        "--episodes",
        "1",
        "--lossless",
        "--task-options",
        "obs_mode=rgbd",
        "image_size=[32,24]",
        "--infos",
        "",
    )
    episode = next(dataset.iterate_episodes([0]))
    assert episode.observations["rgb"].shape[1:] == (24, 32, 3)
    assert demonstrations.replay(dataset)


@pytest.mark.unit
@pytest.mark.parametrize(
    "argv",
    [
        ["--agent", "nobody", "--task", "Stack"],
        ["--agent", "expert", "--task", "Nothing"],
        ["--agent", "planned", "--task", "Stack"],
        ["--agent", "expert", "--task", "Stack", "--episodes", "0"],
        ["--agent", "expert", "--task", "Stack", "--name", "no-version"],
    ],
)
def test_bad_arguments_stop_with_a_message(argv, capsys):
    with pytest.raises(SystemExit) as stop:
        demonstrations.parse_args(argv)
    assert stop.value.code == 2 and "error:" in capsys.readouterr().err


# --- datasets are data: nothing a dataset's files name is imported or run --------------------------------

import json  # noqa: E402
import shutil  # noqa: E402


def plant(metadata_path, marker, **spec_changes):
    """Rewrite a dataset's recorded env spec to run ``touch marker`` through ``os.system`` if anything builds it."""
    metadata = json.loads(metadata_path.read_text())
    spec = {
        **json.loads(metadata["env_spec"]),
        "entry_point": "os:system",
        "kwargs": {"command": f"touch {marker}"},
        **spec_changes,
    }
    metadata["env_spec"] = json.dumps(spec)
    metadata_path.write_text(json.dumps(metadata))


@pytest.fixture(scope="module")
def push_dataset(tmp_path_factory):
    out = tmp_path_factory.mktemp("minari")
    record(out, "--agent", "random", "--task", "Push", "--episodes", "1", "--infos", "")
    return out / "panda_grasp_env" / "push-random-v0" / "data"


@pytest.mark.parametrize("spec_changes", [{}, {"id": "PandaPush-v0"}, {"id": "Payload-v0"}])
def test_replay_never_builds_the_env_a_datasets_entry_point_names(push_dataset, tmp_path, spec_changes):
    folder = tmp_path / "data"
    shutil.copytree(push_dataset, folder)
    plant(folder / "metadata.json", tmp_path / "payload-ran", **spec_changes)
    try:
        with pytest.raises(
            ValueError,
            match=r"metadata.json: env_spec (gives PandaPush-v0 the entry point "
            r"'os:system'|records env id 'Payload-v0', not one of this project's)",
        ):
            demonstrations.replay(minari.MinariDataset(folder))
    finally:
        assert not (tmp_path / "payload-ran").exists(), "the dataset's payload ran"
    from panda_grasp_env.agents.learning import datasets

    with pytest.raises(ValueError, match="metadata.json: env_spec"):
        datasets.open_dataset(folder)
    assert not (tmp_path / "payload-ran").exists()
    # The untouched dataset replays in this project's env.
    assert demonstrations.replay(datasets.open_dataset(push_dataset))


@pytest.mark.unit
def test_a_dataset_without_its_spaces_is_refused_before_minari_would_build_its_env(push_dataset, tmp_path):
    from panda_grasp_env.agents.learning import datasets

    folder = tmp_path / "data"
    shutil.copytree(push_dataset, folder)
    plant(folder / "metadata.json", tmp_path / "payload-ran", id="PandaPush-v0", entry_point="os:system")
    metadata = json.loads((folder / "metadata.json").read_text())
    (folder / "metadata.json").write_text(json.dumps({k: v for k, v in metadata.items() if k != "action_space"}))
    with pytest.raises(ValueError, match="lacks its action_space"):
        datasets.open_dataset(folder)
    assert not (tmp_path / "payload-ran").exists()


def test_planted_shards_are_recorded_again_never_combined(tmp_path, capsys):
    argv = ("--agent", "random", "--task", "Push", "--episodes", "2", "--shard-size", "1", "--infos", "")
    record(tmp_path, *argv)
    shards = sorted((tmp_path / "panda_grasp_env").glob("push-random-shard*-v0"))
    assert len(shards) == 2
    # Every shard swapped for one with the right episode count and a payload in its env spec; the second with
    # no manifest or signature at all.
    for shard in shards:
        plant(shard / "data" / "metadata.json", tmp_path / "payload-ran")
    (shards[1] / "manifest.json").unlink(missing_ok=True)
    (shards[1] / "signatures.json").unlink(missing_ok=True)
    capsys.readouterr()
    dataset = record(tmp_path, *argv)
    out = capsys.readouterr().out
    try:
        assert demonstrations.replay(dataset) and dataset.total_episodes == 2
    finally:
        assert not (tmp_path / "payload-ran").exists(), "a planted shard's payload ran"
    assert "0 of 2 shards already recorded" in out and out.count("recorded again") == 2
    assert all((shard / demonstrations.MANIFEST).is_file() for shard in shards)
