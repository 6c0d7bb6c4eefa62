import os

os.environ.setdefault("MUJOCO_GL", "egl")

import numpy as np  # noqa: E402
import pytest  # noqa: E402

from panda_grasp_env.sim.workcell import Workcell  # noqa: E402


@pytest.fixture(scope="session")
def cell() -> Workcell:
    """One workcell for the session (building the model takes ~0.3 s); tests reset it."""
    return Workcell()


@pytest.fixture
def rng() -> np.random.Generator:
    return np.random.default_rng(1234)


@pytest.fixture(scope="session", autouse=True)
def private_run_key(tmp_path_factory: pytest.TempPathFactory) -> None:
    """Run files are signed with a key under ``$XDG_STATE_HOME``: one for the session, not the user's own."""
    os.environ["XDG_STATE_HOME"] = str(tmp_path_factory.mktemp("state"))
