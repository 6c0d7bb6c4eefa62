"""The RL Zoo recipe (configs/zoo/tqc.yml) runs as the README says: train, enjoy on a server, record a video."""

from __future__ import annotations

import os
import subprocess
import sys
from pathlib import Path

import pytest
import yaml
from testkit import ROOT

ZOO_CONFIG = ROOT / "configs" / "zoo" / "tqc.yml"


def zoo(module: str, tmp_path: Path, *args: str, wrapper: bool = False) -> subprocess.CompletedProcess:
    """``python -m rl_zoo3.<module>`` as the Zoo documents it, or with ``wrapper`` this project's
    ``python -m panda_grasp_env.commands.zoo <module>`` (ids registered, one torch thread on small machines)."""
    env = {k: v for k, v in os.environ.items() if k not in ("DISPLAY", "WAYLAND_DISPLAY")}  # a server
    route = (
        ["panda_grasp_env.commands.zoo", module]
        if wrapper
        else [f"rl_zoo3.{module}", "--gym-packages", "panda_grasp_env"]
    )
    command = [
        sys.executable,
        "-m",
        *route,
        "--algo",
        "tqc",
        "--env",
        "PandaPush-v0",
        "-f",
        str(tmp_path / "logs"),
        *args,
    ]
    return subprocess.run(command, cwd=tmp_path, env=env, capture_output=True, text=True, timeout=600)


@pytest.mark.unit
def test_zoo_hyperparameters_name_registered_ids_and_the_evaluation_start():
    import gymnasium as gym

    import panda_grasp_env  # noqa: F401  (registers the ids)

    for env_id, hyperparameters in yaml.safe_load(ZOO_CONFIG.read_text()).items():
        env = gym.make(env_id, **hyperparameters.get("env_kwargs", {}))  # a typo in a key raises here
        assert isinstance(env.observation_space, gym.spaces.Dict)  # HER needs the goal-env layout
        env.close()


def test_zoo_trains_our_push_with_the_shipped_config_and_enjoy_runs_headless(tmp_path):
    trained = zoo(
        "train",
        tmp_path,
        "-conf",
        str(ZOO_CONFIG),
        "-n",
        "800",
        "-params",
        "learning_starts:400",
        "--eval-freq",
        "400",
        "--eval-episodes",
        "2",
        "--eval-env-kwargs",
        "start_behind_object:0.0",
        "--seed",
        "0",
        wrapper=True,
    )
    assert trained.returncode == 0, trained.stderr[-3000:]
    # No --num-threads given: the wrapper's default, one thread on a machine of <= 2 cores.
    assert ("torch threads: 1 (" in trained.stdout) == ((os.cpu_count() or 1) <= 2)
    run = tmp_path / "logs" / "tqc" / "PandaPush-v0_1"
    assert (run / "PandaPush-v0.zip").is_file() and (run / "evaluations.npz").is_file()
    enjoyed = zoo("enjoy", tmp_path, "-n", "60", "--no-render", "--env-kwargs", "start_behind_object:0.0")
    assert enjoyed.returncode == 0, enjoyed.stderr[-3000:]
    assert "Success rate" in enjoyed.stdout
    # The Zoo's enjoy without --no-render on a server: the env's own error at make, not pygame's at reset.
    shown = zoo("enjoy", tmp_path, "-n", "10")
    assert shown.returncode != 0 and "render_mode='human' needs a display" in shown.stderr
    assert "pygame" not in shown.stderr
    # rl_zoo3.record_video has no --gym-packages: this project's wrapper registers the ids first.
    recorded = zoo("record_video", tmp_path, "-n", "30", "-o", str(tmp_path / "videos"), wrapper=True)
    assert recorded.returncode == 0, recorded.stderr[-3000:]
    videos = list((tmp_path / "videos").glob("*.mp4"))
    assert len(videos) == 1 and videos[0].stat().st_size > 1000


@pytest.mark.unit
def test_the_zoo_wrapper_defaults_to_one_torch_thread_on_small_machines_and_registers_the_ids():
    from panda_grasp_env.commands.zoo import zoo_argv

    argv = ["--algo", "tqc", "--env", "PandaPush-v0"]
    assert zoo_argv("train", argv, cores=2) == [*argv, "--gym-packages", "panda_grasp_env", "--num-threads", "1"]
    assert zoo_argv("enjoy", argv, cores=1)[-2:] == ["--num-threads", "1"]
    assert zoo_argv("train", argv, cores=16) == [*argv, "--gym-packages", "panda_grasp_env"]  # torch's default
    given = [*argv, "--num-threads", "2", "--gym-packages", "panda_grasp_env", "other"]
    assert zoo_argv("train", given, cores=2) == given  # the user's choice stands
    assert zoo_argv("record_video", argv, cores=2) == argv  # it takes neither flag: main sets threads itself
