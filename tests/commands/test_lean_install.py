"""The README's main command on what the README installs: ``python evaluate.py`` with no optional package.

A fresh clone crashed here once: the default protocol plays no mesh task, but judging whether the mesh-trained
checkpoints play the block tasks built their training envs, which need the ``objects`` extra.  This runs the
default protocol -- its planning and one episode of every (agent, task) pair -- in a process in which every
package of an extra that the main command does not install fails to import.
"""

import json
import re
import subprocess
import sys

import tomllib
from testkit import ROOT

#: Import names of the optional extras' packages (``pyproject.toml``) besides the core dependencies.
IMPORT_NAMES = {
    "pybullet": ["pybullet", "pybullet_data", "pybullet_envs"],
    "ray": ["ray"],
    "rl_zoo3": ["rl_zoo3"],
    "minari": ["minari", "h5py"],
    "rliable": ["rliable", "arch"],
    "pandas": ["pandas"],
    "playwright": ["playwright"],
    "mkdocs-material": ["mkdocs", "material"],
    "mkdocstrings": ["mkdocstrings"],
    "pytest": [],  # the test runner itself: it is what runs this test
    "pytest-xdist": [],
    "import-linter": ["importlinter"],  # the layer contracts, run by the suite (tests/test_layout.py)
}

BLOCKED_RUN = """
import importlib.machinery, sys
BLOCKED = set(sys.argv[1].split(","))

class PathFinderWithout(importlib.machinery.PathFinder):
    # Python's own finder of installed modules, blind to the blocked ones: they are absent, as uninstalled
    # (importlib.util.find_spec gives None, and importing one raises ModuleNotFoundError).
    @classmethod
    def find_spec(cls, name, path=None, target=None):
        if name.split(".")[0] in BLOCKED:
            return None
        return super().find_spec(name, path, target)

sys.meta_path[:] = [PathFinderWithout if f is importlib.machinery.PathFinder else f for f in sys.meta_path]
import importlib.util
assert all(importlib.util.find_spec(name) is None for name in BLOCKED), "a blocked package is still found"
from panda_grasp_env.commands import evaluate
sys.exit(evaluate.main(["--no-video", "--seeds", "1", "--out", sys.argv[2]]))
"""


def requirement_name(requirement: str) -> str:
    """The distribution's name in a requirement string (``"minari[create,hdf5]>=0.5"`` -> ``minari``)."""
    return re.match(r"[A-Za-z0-9_.-]+", requirement).group()


def installed_with(names: set[str]) -> set[str]:
    """``names`` and every distribution they require, transitively, as installed here (normalised names)."""
    from importlib.metadata import PackageNotFoundError, requires

    normal = {name.lower().replace("_", "-") for name in names}
    todo = list(normal)
    while todo:
        try:
            needs = requires(todo.pop()) or []
        except PackageNotFoundError:
            continue
        for need in needs:
            if "extra ==" in need:
                continue
            name = requirement_name(need).lower().replace("_", "-")
            if name not in normal:
                normal.add(name)
                todo.append(name)
    return normal


def optional_packages() -> list[str]:
    """The import names (``IMPORT_NAMES``) of every extra's requirement that the core dependencies do not
    install themselves: what a venv made by the README's main command lacks."""
    project = tomllib.loads((ROOT / "pyproject.toml").read_text())["project"]
    core = installed_with({requirement_name(req) for req in project["dependencies"]})
    extras = {requirement_name(req) for reqs in project["optional-dependencies"].values() for req in reqs}
    unknown = sorted(extras - set(IMPORT_NAMES))
    assert not unknown, f"name the import names of {unknown} in IMPORT_NAMES"
    missing = [extra for extra in extras if extra.lower().replace("_", "-") not in core]
    return sorted({name for extra in missing for name in IMPORT_NAMES[extra]})


def test_the_default_protocol_runs_with_every_optional_package_missing(tmp_path):
    blocked = optional_packages()
    assert "pybullet_data" in blocked and "ray" in blocked
    out = tmp_path / "quick"
    done = subprocess.run(
        [sys.executable, "-c", BLOCKED_RUN, ",".join(blocked), str(out)],
        capture_output=True,
        text=True,
        timeout=1200,
        cwd=ROOT,
    )
    assert done.returncode == 0, done.stderr[-3000:]
    results = json.loads((out / "results.json").read_text())
    pairs = results["metrics"]
    assert len(pairs) >= 40 and all(m["episodes"] == 1 for m in pairs.values())
    assert "grasp_mesh_dqn/GraspClutter" in pairs  # judged on a block task without the mesh set
