"""The installed import names: everything lives under ``panda_grasp_env``; no generic top-level name is claimed.

The folders ``agents/`` and ``perception/`` install as ``panda_grasp_env.agents`` and
``panda_grasp_env.perception`` (pyproject's package-dir).  ``agents`` is also what openai-agents installs,
and a PyPI package is named ``perception``: research code must be able to have both."""

from __future__ import annotations

import ast
import os
import re
import shutil
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


def wheel_layout(tmp_path: Path) -> Path:
    """The package's modules as a wheel lays them out (``agents/`` and ``perception/`` inside
    ``panda_grasp_env/``), with ``pyproject.toml`` beside them: what import-linter reads its graph from."""
    root = tmp_path / "wheel"
    for folder, installed in (("panda_grasp_env", ""), ("agents", "agents"), ("perception", "perception")):
        for path in (ROOT / folder).rglob("*.py"):
            target = root / "panda_grasp_env" / installed / path.relative_to(ROOT / folder)
            target.parent.mkdir(parents=True, exist_ok=True)
            shutil.copy(path, target)
    shutil.copy(ROOT / "pyproject.toml", root)
    return root


def lint_imports(root: Path) -> subprocess.CompletedProcess:
    """import-linter's command on the contracts of ``pyproject.toml`` (``[tool.importlinter]``), in ``root``."""
    command = [str(Path(sys.executable).parent / "lint-imports"), "--no-cache"]
    environment = {**os.environ, "PYTHONPATH": str(root)}
    return subprocess.run(command, cwd=root, env=environment, capture_output=True, text=True, timeout=300)


def test_the_import_contracts_hold(tmp_path):
    """The layers, the agents' and the evaluation's sub-layers, and no cycles (``pyproject.toml``)."""
    done = lint_imports(wheel_layout(tmp_path))
    assert done.returncode == 0 and "Contracts: 4 kept, 0 broken." in done.stdout, done.stdout[-3000:]
    analysed = int(re.search(r"Analyzed (\d+) files", done.stdout).group(1))
    assert analysed == len(module_files())  # agents/ and perception/ too


@pytest.mark.parametrize(
    ("planted", "contract"),
    [
        ({"sim/planted.py": "from panda_grasp_env.tasks import base\n"}, "Layers"),
        ({"perception/planted.py": "import panda_grasp_env.agents.evaluation.report\n"}, "Layers"),
        ({"agents/policies/planted.py": "import panda_grasp_env.agents.learning.training\n"}, "Agents"),
        ({"agents/evaluation/metrics.py": "import panda_grasp_env.agents.evaluation.runner\n"}, "Evaluation"),
        (
            {
                "sim/planted_a.py": "import panda_grasp_env.sim.planted_b\n",
                "sim/planted_b.py": "import panda_grasp_env.sim.planted_a\n",
            },
            "No cycles",
        ),
    ],
)
def test_an_import_planted_against_the_contracts_is_caught(tmp_path, planted, contract):
    root = wheel_layout(tmp_path)
    for name, source in planted.items():  # a new module, or an import added to one
        path = root / "panda_grasp_env" / name
        path.write_text((path.read_text() if path.exists() else "") + source)
    done = lint_imports(root)
    assert done.returncode != 0 and re.search(rf"^{contract}.* BROKEN", done.stdout, re.M), done.stdout[-3000:]


def test_every_agents_and_evaluation_module_has_its_place_in_the_contracts():
    """A new module of ``agents/`` lands in a sub-package, and one of the evaluation in its layers."""
    tomllib = pytest.importorskip("tomllib")  # Python >= 3.11
    contracts = tomllib.loads((ROOT / "pyproject.toml").read_text())["tool"]["importlinter"]["contracts"]
    listed = {m.strip() for c in contracts if c["type"] == "layers" for layer in c["layers"] for m in layer.split(":")}
    package = "panda_grasp_env.agents.evaluation"
    assert {m for m in module_files() if m.startswith(f"{package}.")} <= listed
    assert {".".join(m.split(".")[:3]) for m in module_files() if m.startswith("panda_grasp_env.agents.")} <= listed


@pytest.mark.unit
def test_the_tests_mirror_the_layers():
    """A layer's tests sit in a folder named after it (the agents' in one per sub-package, and the fall model's
    training, a package of learning, in its own; the falls recorder, counted as tooling, in its own); only the
    project-wide checks sit at the top of ``tests/``."""
    agents = [f"agents/{package}" for package in ("policies", "evaluation", "learning", "learning/falls")]
    layer_folders = {*LAYERS, "falls", *agents}
    layer_folders -= {"agents", "tooling"}
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
