"""The RL Zoo recipe (configs/zoo/tqc.yml) runs as the README says: train, then enjoy on a server."""

from __future__ import annotations

import os
import subprocess
import sys
from pathlib import Path

import yaml

ROOT = Path(__file__).resolve().parents[1]
ZOO_CONFIG = ROOT / "configs" / "zoo" / "tqc.yml"


def zoo(module: str, tmp_path: Path, *args: str) -> subprocess.CompletedProcess:
    env = {k: v for k, v in os.environ.items() if k not in ("DISPLAY", "WAYLAND_DISPLAY")}  # a server
    command = [sys.executable, "-m", f"rl_zoo3.{module}", "--algo", "tqc", "--env", "PandaPush-v0",
               "--gym-packages", "panda_grasp_env", "-f", str(tmp_path / "logs"), *args]  # fmt: skip
    return subprocess.run(command, cwd=tmp_path, env=env, capture_output=True, text=True, timeout=600)


def test_zoo_hyperparameters_name_registered_ids_and_the_evaluation_start():
    import gymnasium as gym

    import panda_grasp_env  # noqa: F401  (registers the ids)

    for env_id, hyperparameters in yaml.safe_load(ZOO_CONFIG.read_text()).items():
        env = gym.make(env_id, **hyperparameters.get("env_kwargs", {}))  # a typo in a key raises here
        assert isinstance(env.observation_space, gym.spaces.Dict)  # HER needs the goal-env layout
        env.close()


def test_zoo_trains_our_push_with_the_shipped_config_and_enjoy_runs_headless(tmp_path):
    trained = zoo("train", tmp_path, "-conf", str(ZOO_CONFIG), "-n", "800", "-params", "learning_starts:400",
                  "--eval-freq", "400", "--eval-episodes", "2", "--eval-env-kwargs", "start_behind_object:0.0",
                  "--seed", "0", "--num-threads", "1")  # fmt: skip
    assert trained.returncode == 0, trained.stderr[-3000:]
    run = tmp_path / "logs" / "tqc" / "PandaPush-v0_1"
    assert (run / "PandaPush-v0.zip").is_file() and (run / "evaluations.npz").is_file()
    enjoyed = zoo("enjoy", tmp_path, "-n", "60", "--no-render", "--env-kwargs", "start_behind_object:0.0")
    assert enjoyed.returncode == 0, enjoyed.stderr[-3000:]
    assert "Success rate" in enjoyed.stdout
