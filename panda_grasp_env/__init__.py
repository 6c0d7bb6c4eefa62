"""panda_grasp_env: a MuJoCo Franka Panda workcell for tower building, tower breaking and grasping.

Importing the package imports every task module, which registers the task's Gymnasium ids
(see ``registration.py``).
"""

import importlib.abc
import importlib.util
import os
import re
import sys
from pathlib import Path

# Headless machines have no X display: render offscreen through EGL unless told otherwise.
# (Must happen before mujoco is first imported.)
if "DISPLAY" not in os.environ:
    os.environ.setdefault("MUJOCO_GL", "egl")


class _CheckoutFolders(importlib.abc.MetaPathFinder):
    """Imports ``panda_grasp_env.agents`` and ``panda_grasp_env.perception`` from the top-level ``agents/`` and
    ``perception/`` folders of the source checkout this package sits in.

    A wheel installs those folders inside the package.  A source checkout keeps them beside it, and an
    editable install maps them to the checkout it was made from: without this finder, a second checkout
    imported its own ``panda_grasp_env`` with the first one's agents, and one without an install imported
    no ``panda_grasp_env.perception`` at all.
    """

    def __init__(self, root: Path) -> None:
        self.folders = {f"{__name__}.{name}": root / name for name in ("agents", "perception")}

    def find_spec(self, fullname, path=None, target=None):  # noqa: ANN001, ANN201  (the importlib protocol)
        folder = self.folders.get(fullname)
        if folder is None:
            return None
        return importlib.util.spec_from_file_location(
            fullname, folder / "__init__.py", submodule_search_locations=[str(folder)]
        )


def _in_a_checkout(root: Path) -> bool:
    """Whether ``root`` is this project's source checkout (not, say, a site-packages holding other ``agents``)."""
    pyproject = root / "pyproject.toml"
    return (
        not (Path(__file__).parent / "agents").exists()
        and pyproject.is_file()
        and re.search(r'^name\s*=\s*"panda[-_]grasp[-_]env"', pyproject.read_text(), re.MULTILINE) is not None
        and all((root / name / "__init__.py").is_file() for name in ("agents", "perception"))
    )


_root = Path(__file__).resolve().parent.parent
if _in_a_checkout(_root) and not any(isinstance(f, _CheckoutFolders) for f in sys.meta_path):
    sys.meta_path.insert(0, _CheckoutFolders(_root))

import panda_grasp_env.tasks  # noqa: E402, F401  (registers the tasks and their ids)
from panda_grasp_env.registration import ENV_IDS, TASKS  # noqa: E402
from panda_grasp_env.sim.motion import WORKSPACE  # noqa: E402
from panda_grasp_env.sim.workcell import SPAWN_REGION  # noqa: E402

__version__ = "0.1.0"
#: ``WORKSPACE``: the x, y, z bounds (3, 2) a primitive's target may take, world metres (the table top is z = 0);
#: ``SPAWN_REGION``: the x, y bounds (2, 2) inside it where resets lay objects out.
__all__ = ["ENV_IDS", "SPAWN_REGION", "TASKS", "WORKSPACE"]
