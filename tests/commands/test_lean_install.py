"""The README's main command on what the README installs, and a plain install without the learning stack.

A fresh clone crashed here once: the default protocol plays no mesh task, but judging whether the mesh-trained
checkpoints play the block tasks built their training envs, which need the ``objects`` extra.  This runs the
default agents on three of its tasks (one a clutter task the mesh-trained checkpoints are judged on): their
planning and one episode of every (agent, task) pair, in a process in which every package of an extra that the
main command does not install fails to import.  A plain ``pip install panda_grasp_env`` (no ``learn`` extra: no
torch, SB3, sb3-contrib, tensorboard or safetensors) makes, resets and steps every env id, plays the scripted
agents through ``evaluate.py``, and refuses a learned agent and ``train.py`` with one line naming the extra.
``.ci/run`` runs the whole default protocol and the plain install's in venvs that hold only what each installs.
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
    # The learn extra (the README's main command installs it; a plain install does not).
    "torch": ["torch"],
    "stable-baselines3": ["stable_baselines3"],
    "sb3-contrib": ["sb3_contrib"],
    "tensorboard": ["tensorboard"],
    "safetensors": ["safetensors"],
}
#: The extra the README's main command installs beside the core dependencies.
MAIN_EXTRAS = ("learn",)

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
sys.exit(evaluate.main(["--no-video", "--seeds", "1", "--tasks", sys.argv[3], "--out", sys.argv[2]]))
"""
#: The default protocol's tasks that the first test plays.
PLAYED_TASKS = "GraspClutter,TowerBuild,Push"


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


def optional_packages(installed_extras: tuple[str, ...] = MAIN_EXTRAS) -> list[str]:
    """The import names (``IMPORT_NAMES``) of every extra's requirement that the core dependencies and
    ``installed_extras`` do not install themselves: what a venv made by the README's main command lacks (or,
    with none, a plain ``pip install panda_grasp_env``)."""
    project = tomllib.loads((ROOT / "pyproject.toml").read_text())["project"]
    extras_of = project["optional-dependencies"]
    core_requirements = [*project["dependencies"], *(req for extra in installed_extras for req in extras_of[extra])]
    core = installed_with({requirement_name(req) for req in core_requirements} - {project["name"]})
    extras = {requirement_name(req) for reqs in extras_of.values() for req in reqs} - {project["name"]}
    unknown = sorted(extras - set(IMPORT_NAMES))
    assert not unknown, f"name the import names of {unknown} in IMPORT_NAMES"
    missing = [extra for extra in extras if extra.lower().replace("_", "-") not in core]
    return sorted({name for extra in missing for name in IMPORT_NAMES[extra]})


def run_blocked(script: str, blocked: list[str], out, tasks: str = PLAYED_TASKS) -> subprocess.CompletedProcess:
    """``script`` (one of the above: it reads the blocked names, ``out`` and ``tasks``) in a fresh interpreter."""
    command = [sys.executable, "-c", script, ",".join(blocked), str(out), tasks]
    return subprocess.run(command, capture_output=True, text=True, timeout=1200, cwd=ROOT)


def test_the_default_protocol_runs_with_every_optional_package_missing(tmp_path):
    blocked = optional_packages()
    assert "pybullet_data" in blocked and "ray" in blocked
    out = tmp_path / "quick"
    done = run_blocked(BLOCKED_RUN, blocked, out)
    assert done.returncode == 0, done.stderr[-3000:]
    results = json.loads((out / "results.json").read_text())
    pairs = results["metrics"]
    assert {key.split("/")[1] for key in pairs} == set(PLAYED_TASKS.split(","))
    assert len(pairs) >= 10 and all(m["episodes"] == 1 for m in pairs.values())
    assert "grasp_mesh_dqn/GraspClutter" in pairs  # judged on a block task without the mesh set


CORE_RUN = (
    BLOCKED_RUN.split("from panda_grasp_env.commands import evaluate")[0]
    + """
import gymnasium as gym
from panda_grasp_env.registration import ENV_IDS
from panda_grasp_env.commands import evaluate

for env_id in sorted(ENV_IDS):  # every id: made, reset and stepped by a random agent
    env = gym.make(env_id)
    env.reset(seed=0)
    env.action_space.seed(0)
    for _ in range(2):
        env.step(env.action_space.sample())
    env.close()
print("ids", len(ENV_IDS))
try:
    from panda_grasp_env.agents.policies.learned import LearnedAgent
    LearnedAgent("tower_build_dqn")
except ModuleNotFoundError as error:
    print("learned:", error)
agents = "random,planned,oracle,expert,planned_lookahead,planned_lookahead_learned,tower_build_dqn"
sys.exit(evaluate.main(["--agents", agents, "--no-video", "--seeds", "1", "--tasks", sys.argv[3], "--out", sys.argv[2]]))
"""
)


def test_a_plain_install_runs_every_id_and_the_scripted_agents_and_names_the_learn_extra(tmp_path):
    blocked = [name for name in optional_packages(installed_extras=()) if name not in IMPORT_NAMES["pybullet"]]
    assert {"torch", "stable_baselines3", "sb3_contrib", "safetensors"} <= set(blocked)
    out = tmp_path / "core"
    done = run_blocked(CORE_RUN, blocked, out, tasks="TowerBuild,Push,StructuresSample")
    assert done.returncode == 0, done.stderr[-3000:]
    assert "learned: learned agent tower_build_dqn needs the learn extra" in done.stdout
    assert "pip install 'panda_grasp_env[learn]'" in done.stdout
    results = json.loads((out / "results.json").read_text())
    agents = {key.split("/")[0] for key in results["metrics"]}
    assert agents == {"random", "planned", "oracle", "expert", "planned_lookahead"}
    assert "needs the learn extra" in results["protocol"]["skipped"]["tower_build_dqn/TowerBuild"]
    assert "needs the learn extra" in results["protocol"]["skipped"]["planned_lookahead_learned/StructuresSample"]
    train_help = "import runpy; sys.argv = ['train.py', '--help']; runpy.run_path('train.py', run_name='__main__')"
    trained = run_blocked(CORE_RUN.split("import gymnasium")[0] + train_help, blocked, out)
    assert trained.returncode == 2 and "error: train.py needs the learn extra" in trained.stderr
