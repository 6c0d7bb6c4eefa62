import ctypes
import gc
import json
import os
import sys
from collections.abc import Callable, Iterator
from pathlib import Path

import panda_grasp_env  # noqa: E402, F401  (first: it chooses MUJOCO_GL before mujoco is imported)

# isort: split

import mujoco  # noqa: E402
import numpy as np  # noqa: E402
import pytest  # noqa: E402

from panda_grasp_env.model.scene import FINGER_JOINTS  # noqa: E402
from panda_grasp_env.sim.workcell import Workcell  # noqa: E402


@pytest.fixture
def soften_finger_limits() -> Callable[[mujoco.MjModel], None]:
    """A function giving a model's finger joint limits MuJoCo's default softness, as before commit 2f82af1: a
    test of the stiff limits runs its scenario this way too, to show that the scenario still provokes the fault."""

    default = mujoco.MjSpec().worldbody.add_body().add_joint()  # MuJoCo's own defaults, not copies of them

    def soften(model: mujoco.MjModel) -> None:
        for name in FINGER_JOINTS:
            joint = model.joint(name).id
            model.jnt_solref[joint] = default.solref_limit
            model.jnt_solimp[joint] = default.solimp_limit

    return soften


@pytest.fixture(scope="session")
def cell() -> Workcell:
    """One workcell for the session (building the model takes ~0.3 s); tests reset it."""
    return Workcell()


@pytest.fixture
def rng() -> np.random.Generator:
    return np.random.default_rng(1234)


@pytest.fixture(autouse=True)
def collect_after_each_test() -> Iterator[None]:
    """Each test starts from the memory the one before left: what a test made and dropped in reference cycles of
    libraries' objects (SB3's models and loggers, torch modules) is collected after it, and the heap it freed
    goes back to the system, so that a worker process does not carry every test's garbage (peak RSS of a
    worker: 6.1 GB without, 4.4 GB collecting per module).  The package's own objects are freed without it:
    ``tests/gym_api/test_release.py`` checks envs with the collector off."""
    yield
    gc.collect()
    if sys.platform == "linux":  # and hand the freed heap back to the system (glibc keeps it for reuse otherwise)
        ctypes.CDLL("libc.so.6").malloc_trim(0)


@pytest.fixture(scope="session", autouse=True)
def private_run_key(tmp_path_factory: pytest.TempPathFactory) -> None:
    """Run files are signed with a key under ``$XDG_STATE_HOME``: one for the session, not the user's own."""
    os.environ["XDG_STATE_HOME"] = str(tmp_path_factory.mktemp("state"))


@pytest.fixture(scope="session")
def finished_run(tmp_path_factory: pytest.TempPathFactory) -> Path:
    """A tiny pixel-mode DQN run, trained in two sessions (the second resumes the first); one per test process,
    for the tests of training, records, shipped checkpoints and evaluate.py."""
    from testkit import CONFIGS, TINY_DQN

    from panda_grasp_env.commands import train

    runs = tmp_path_factory.mktemp("runs")
    config = str(CONFIGS / "grasp_clutter_dqn.yaml")
    assert train.main(["--config", config, "--runs", str(runs), "--no-progress", *TINY_DQN, "total_steps=6"]) == 0
    run = runs / "grasp_clutter_dqn-seed0"
    assert json.loads((run / "progress.json").read_text())["steps"] == 6
    assert train.main(["--resume", str(run), "total_steps=12", "--no-progress"]) == 0
    return run


@pytest.fixture(scope="session")
def fall_dataset(tmp_path_factory: pytest.TempPathFactory) -> Path:
    """A recorded falling-tower dataset, 10 sequences of ``FALL_RECORDING``; one per test process, for the tests
    of the recorder (``tests/falls``) and of the fall model (``tests/agents/learning/falls``)."""
    from testkit import FALL_RECORDING

    from panda_grasp_env.falls.recorder import record_dataset
    from panda_grasp_env.falls.settings import RecorderSettings

    out = tmp_path_factory.mktemp("falls")
    record_dataset(out, 10, RecorderSettings(**FALL_RECORDING), workers=1, progress=False)
    return out
