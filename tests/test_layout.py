"""The installed import names: everything lives under ``panda_grasp_env``; no generic top-level name is claimed.

The folders ``agents/`` and ``perception/`` install as ``panda_grasp_env.agents`` and
``panda_grasp_env.perception`` (pyproject's package-dir).  ``agents`` is also what openai-agents installs,
and a PyPI package is named ``perception``: research code must be able to have both."""

from __future__ import annotations

import ast
import json
import re
import subprocess
import sys
from pathlib import Path

import pytest
from testkit import ROOT

SOURCE_DIRS = ("panda_grasp_env", "agents", "perception", "tests", "benchmarks")
GENERIC = ("agents", "perception")


def python_files() -> list[Path]:
    files = [ROOT / "train.py", ROOT / "evaluate.py"]
    for folder in SOURCE_DIRS:
        files += sorted((ROOT / folder).rglob("*.py"))
    return files


def test_no_module_imports_a_generic_top_level_name():
    offenders = []
    for path in python_files():
        for node in ast.walk(ast.parse(path.read_text(), str(path))):
            names = [a.name for a in node.names] if isinstance(node, ast.Import) else []
            if isinstance(node, ast.ImportFrom) and node.level == 0 and node.module:
                names = [node.module]
            offenders += [f"{path.relative_to(ROOT)}:{node.lineno} {n}" for n in names if n.split(".")[0] in GENERIC]
    assert offenders == []


#: Layers, bottom first: a module may import its own layer and those below, never one above.  Inside the env
#: each layer is a folder; the Gym API is the package's own modules.  ``registration`` imports nothing of
#: ours and sits at the bottom because every task file declares its ids through it.
FOUNDATION = ("panda_grasp_env.geometry", "panda_grasp_env.registration", "panda_grasp_env.config_fields")
ENV_LAYERS = ("model", "control", "sim", "primitives", "tasks")
LAYERS = ("foundation", "perception", *ENV_LAYERS, "gym_api", "tooling", "agents", "commands")


def module_files() -> dict[str, Path]:
    """Our modules by installed name."""
    modules = {}
    for folder, package in (
        ("panda_grasp_env", "panda_grasp_env"),
        ("agents", "panda_grasp_env.agents"),
        ("perception", "panda_grasp_env.perception"),
    ):
        for path in (ROOT / folder).rglob("*.py"):
            parts = [p for p in path.relative_to(ROOT / folder).with_suffix("").parts if p != "__init__"]
            modules[".".join([package, *parts])] = path
    return modules


#: Size limits of our modules (issue 58): the env joins the parts and stays short; no module, and no class, grows
#: past what a reader can hold.  Lines are the file's; methods are the functions defined directly in a class body.
ENV_MAX_LINES, MODULE_MAX_LINES, CLASS_MAX_METHODS = 300, 500, 25


def test_modules_and_classes_stay_within_the_size_limits():
    too_big = []
    for name, path in sorted(module_files().items()):
        text = path.read_text()
        lines, most = len(text.splitlines()), ENV_MAX_LINES if name == "panda_grasp_env.env" else MODULE_MAX_LINES
        if lines > most:
            too_big.append(f"{name}: {lines} lines, more than {most}")
        for node in ast.walk(ast.parse(text, str(path))):
            if isinstance(node, ast.ClassDef):
                methods = sum(isinstance(item, (ast.FunctionDef, ast.AsyncFunctionDef)) for item in node.body)
                if methods > CLASS_MAX_METHODS:
                    too_big.append(f"{name}.{node.name}: {methods} methods, more than {CLASS_MAX_METHODS}")
    assert too_big == []


def import_graph() -> dict[str, set[str]]:
    """Module -> our modules it imports anywhere in its body (functions and ``TYPE_CHECKING`` blocks too)."""
    modules = module_files()
    graph: dict[str, set[str]] = {}
    for name, path in modules.items():
        imported = set()
        for node in ast.walk(ast.parse(path.read_text(), str(path))):
            if isinstance(node, ast.ImportFrom) and node.level == 0 and node.module:
                imported |= {node.module} | {f"{node.module}.{a.name}" for a in node.names}
            elif isinstance(node, ast.Import):
                imported |= {a.name for a in node.names}
        graph[name] = {m for m in imported if m in modules and m != name}
    return graph


def layer(module: str) -> str:
    if module in FOUNDATION:
        return "foundation"
    inside = module.removeprefix("panda_grasp_env.").split(".")[0]
    if inside in ("perception", "agents", "commands", *ENV_LAYERS):
        return inside
    if inside in ("tooling", "falls"):
        return "tooling"
    return "gym_api"


@pytest.mark.unit
def test_every_env_module_is_in_a_layer_folder_or_the_gym_api():
    """Nothing new lands at the package's top level by accident: those modules are the Gym API."""
    top_level = {p.stem for p in (ROOT / "panda_grasp_env").glob("*.py")}
    gym_api = {"env", "env_options", "actions", "observations", "randomization"}
    assert top_level == {"__init__", "geometry", "registration", "config_fields", *gym_api}


def test_no_import_cycles():
    graph, state, cycles = import_graph(), {}, []

    def visit(module: str, path: list[str]) -> None:
        state[module] = "open"
        for target in sorted(graph[module]):
            if state.get(target) == "open":
                cycles.append(path[path.index(target) :] + [target] if target in path else [module, target])
            elif target not in state:
                visit(target, [*path, target])
        state[module] = "done"

    for module in sorted(graph):
        if module not in state:
            visit(module, [module])
    assert cycles == []


def test_no_module_imports_a_layer_above_its_own():
    rank = {name: i for i, name in enumerate(LAYERS)}
    upward = [
        f"{m} ({layer(m)}) -> {t} ({layer(t)})"
        for m, targets in import_graph().items()
        for t in targets
        if rank[layer(t)] > rank[layer(m)]
    ]
    assert upward == []


def test_the_simulation_imports_nothing_of_the_tasks_or_the_gym_api():
    sim_imports = [(m, t) for m, targets in import_graph().items() if layer(m) == "sim" for t in targets]
    assert [f"{m} -> {t}" for m, t in sim_imports if layer(t) in ("tasks", "gym_api")] == []


@pytest.mark.parametrize("folder", ["sim", "primitives"])
def test_inside_a_layer_a_module_imports_only_the_modules_the_reference_page_lists_before_it(folder):
    """docs/reference/simulation.md lists the modules bottom first; every module of the folder is on it."""
    page = (ROOT / "docs" / "reference" / "simulation.md").read_text()
    order = [m for m in re.findall(r"^::: (\S+)$", page, re.M) if layer(m) == folder]
    assert set(order) == {m for m in module_files() if layer(m) == folder and m != f"panda_grasp_env.{folder}"}
    graph = import_graph()
    assert [f"{m} -> {t}" for i, m in enumerate(order) for t in graph[m] if t in order[i + 1 :]] == []


def step_observers_added() -> list[tuple[str, str]]:
    """(module, the observer's source text) of every ``add_observer`` call in our modules."""
    calls = []
    for name, path in module_files().items():
        for node in ast.walk(ast.parse(path.read_text(), str(path))):
            if isinstance(node, ast.Call) and isinstance(node.func, ast.Attribute) and node.func.attr == "add_observer":
                calls.append((name, ast.unparse(node.args[0])))
    return calls


@pytest.mark.unit
def test_what_runs_after_every_control_step_is_added_from_above_the_simulation():
    """The stepping calls up only through the observers the layers above add to ``cell.physics`` (a task's
    ``on_control_step`` and the video capture from the env, recorders from tooling), never by a call the
    import graph cannot see: inside sim/ and below, the workcell adds its own collateral monitor, nothing else."""
    rank = {name: i for i, name in enumerate(LAYERS)}
    added = step_observers_added()
    assert [(m, o) for m, o in added if rank[layer(m)] <= rank["sim"]] == [
        ("panda_grasp_env.sim.workcell", "self.collateral.on_control_step")
    ]
    assert ("panda_grasp_env.env", "self.task.on_control_step") in added
    assert {layer(m) for m, _ in added} == {"sim", "gym_api", "tooling"}


#: The evaluation sub-package, bottom first: a module imports only those before it.  The benchmarks (ids, options,
#: seed counts) and the metrics stand alone; an episode is played from the protocol's spec; the runner and the
#: report build on episodes.
EVALUATION = ("benchmarks", "metrics", "protocol", "episodes", "runner", "report")


@pytest.mark.unit
def test_the_evaluation_modules_import_only_those_below_them():
    package = "panda_grasp_env.agents.evaluation"
    rank = {f"{package}.{name}": i for i, name in enumerate(EVALUATION)}
    assert {m for m in module_files() if m.startswith(f"{package}.")} == set(rank)  # a new module takes a place
    graph = import_graph()
    upward = [f"{m} -> {t}" for m in rank for t in graph[m] if rank.get(t, -1) > rank[m]]
    assert upward == []


#: The agents' sub-packages, bottom first: evaluation plays the policies; learning validates its runs through
#: evaluation's episodes and metrics.  Nothing else sits in agents/ (its ``checkpoints/`` are package data).
AGENT_PACKAGES = ("policies", "evaluation", "learning")
#: The only imports against that order: a learned agent reads what learning wrote, its training config (the env
#: and the view of it the policy was trained on) and its policy files.  They close a loop between the
#: sub-packages, never between modules (``test_no_import_cycles``): config and policy_files import nothing of
#: evaluation or of the policies.
LEARNED_AGENT_READS = {
    "panda_grasp_env.agents.policies.learned -> panda_grasp_env.agents.learning.config",
    "panda_grasp_env.agents.policies.learned -> panda_grasp_env.agents.learning.policy_files",
}


def test_the_agents_sub_packages_import_only_those_below_them():
    rank = {name: i for i, name in enumerate(AGENT_PACKAGES)}
    package_of = {m: m.split(".")[2] for m in module_files() if m.startswith("panda_grasp_env.agents.")}
    assert set(package_of.values()) == set(rank)  # every module is in a sub-package
    graph = import_graph()
    upward = {
        f"{m} -> {t}"
        for m in package_of
        for t in graph[m] & package_of.keys()
        if rank[package_of[t]] > rank[package_of[m]]
    }
    assert upward == LEARNED_AGENT_READS


@pytest.mark.unit
def test_the_tests_mirror_the_layers():
    """A layer's tests sit in a folder named after it (the agents' in one per sub-package; the falls package,
    counted as tooling, in its own); only the project-wide checks sit at the top of ``tests/``."""
    layer_folders = {*LAYERS, "falls", *(f"agents/{package}" for package in AGENT_PACKAGES)} - {"agents", "tooling"}
    folders = {path.parent.relative_to(ROOT / "tests").as_posix() for path in (ROOT / "tests").rglob("test_*.py")}
    assert folders - {"."} <= layer_folders
    top = sorted(path.name for path in (ROOT / "tests").glob("test_*.py"))
    assert top == ["test_docs_code.py", "test_layout.py", "test_peer_benchmark.py"]


@pytest.mark.unit
def test_every_source_package_is_installed_under_panda_grasp_env():
    tomllib = pytest.importorskip("tomllib")  # Python >= 3.11
    config = tomllib.loads((ROOT / "pyproject.toml").read_text())["tool"]["setuptools"]
    folders = {name: config["package-dir"].get(name, name.replace(".", "/")) for name in config["packages"]}
    found = {
        str(p.parent.relative_to(ROOT))
        for d in ("panda_grasp_env", "agents", "perception")
        for p in (ROOT / d).rglob("__init__.py")
    }
    assert set(folders.values()) == found and all(name.startswith("panda_grasp_env") for name in folders)


def test_outside_the_repository_only_panda_grasp_env_is_importable(tmp_path):
    script = (
        "import importlib.util as u, json\n"
        "import panda_grasp_env.agents.policies.learned, panda_grasp_env.perception.heightmap\n"
        "print(json.dumps({n: u.find_spec(n) is not None for n in ('agents', 'perception')}))\n"
    )
    done = subprocess.run([sys.executable, "-c", script], cwd=tmp_path, capture_output=True, text=True, timeout=300)
    assert done.returncode == 0, done.stderr[-2000:]
    found = done.stdout.strip().splitlines()[-1]
    if '"agents": true' in found:  # CI installs openai-agents beside the project in a later step
        pytest.skip("another package provides 'agents' here")
    assert found == '{"agents": false, "perception": false}'


@pytest.mark.parametrize("installed", [True, False], ids=["beside-an-editable-install", "without-an-install"])
def test_a_second_checkout_runs_its_own_code(tmp_path, installed):
    """A copy of the checkout imports all three packages from itself: with this checkout installed editable,
    the install's mapping of agents/ and perception/ must not win; without an install, both must import."""
    import shutil

    checkout = tmp_path / "other-checkout"
    for folder in ("panda_grasp_env", "agents", "perception"):
        shutil.copytree(ROOT / folder, checkout / folder, ignore=shutil.ignore_patterns("checkpoints", "__pycache__"))
    shutil.copy(ROOT / "pyproject.toml", checkout)
    forget_the_install = (
        "sys.meta_path[:] = [f for f in sys.meta_path if 'editable' not in type(f).__module__]\n"
        f"sys.path[:] = [p for p in sys.path if p.rstrip('/') != {str(ROOT)!r}]\n"
    )
    script = (
        "import json, sys\n"
        + ("" if installed else forget_the_install)
        + "import panda_grasp_env, panda_grasp_env.agents.policies.towers, panda_grasp_env.perception.heightmap\n"
        "print(json.dumps([sys.modules[n].__file__ for n in ('panda_grasp_env', 'panda_grasp_env.agents',\n"
        "    'panda_grasp_env.perception', 'panda_grasp_env.agents.policies.towers')]))\n"
    )
    done = subprocess.run([sys.executable, "-c", script], cwd=checkout, capture_output=True, text=True, timeout=300)
    assert done.returncode == 0, done.stderr[-2000:]
    files = json.loads(done.stdout.strip().splitlines()[-1])
    assert all(Path(f).is_relative_to(checkout) for f in files), files


@pytest.mark.unit
def test_a_runs_commit_label_sees_changes_anywhere_in_the_repository(monkeypatch):
    # The label a card carries ("+changes": code no commit holds) must look at agents/, perception/ and the
    # entry scripts too, not only at the panda_grasp_env/ folder that holds the function.
    from panda_grasp_env.tooling import runs

    calls = []

    def fake_git(command, **kwargs):
        calls.append(command)
        changed = " M agents/learning/training.py\n" if "status" in command else ""
        return subprocess.CompletedProcess(command, 0, stdout=changed or "abc1234\n", stderr="")

    monkeypatch.setattr(runs.subprocess, "run", fake_git)
    assert runs.commit.__wrapped__() == "abc1234+changes"
    assert all(Path(command[command.index("-C") + 1]) == ROOT for command in calls)


def test_importing_the_env_leaves_jax_out_while_qpsolvers_keeps_its_solvers():
    """qpsolvers' jaxopt backend imports jax before finding jaxopt missing; the package skips that import."""

    def run(code: str) -> dict:
        done = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True)
        return json.loads(done.stdout.strip().splitlines()[-1])

    report = "print(json.dumps({'jax': 'jax' in sys.modules, 'solvers': qpsolvers.available_solvers}))"
    plain = run(f"import json, sys, qpsolvers; {report}")
    if not plain["jax"]:
        pytest.skip("qpsolvers does not import jax here (jax not installed, or jaxopt is)")
    ours = run(f"import json, sys, panda_grasp_env, qpsolvers; {report}")
    assert not ours["jax"] and ours["solvers"] == plain["solvers"]
