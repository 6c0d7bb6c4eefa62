"""The installed import names: everything lives under ``panda_grasp_env``; no generic top-level name is claimed.

The folders ``agents/`` and ``perception/`` install as ``panda_grasp_env.agents`` and
``panda_grasp_env.perception`` (pyproject's package-dir).  ``agents`` is also what openai-agents installs,
and a PyPI package is named ``perception``: research code must be able to have both."""

from __future__ import annotations

import ast
import subprocess
import sys
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]
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


def test_every_source_package_is_installed_under_panda_grasp_env():
    tomllib = pytest.importorskip("tomllib")  # Python >= 3.11
    config = tomllib.loads((ROOT / "pyproject.toml").read_text())["tool"]["setuptools"]
    folders = {name: config["package-dir"].get(name, name.replace(".", "/")) for name in config["packages"]}
    found = {str(p.parent.relative_to(ROOT)) for d in ("panda_grasp_env", "agents", "perception")
             for p in (ROOT / d).rglob("__init__.py")}  # fmt: skip
    assert set(folders.values()) == found and all(name.startswith("panda_grasp_env") for name in folders)


def test_outside_the_repository_only_panda_grasp_env_is_importable(tmp_path):
    script = (
        "import importlib.util as u, json\n"
        "import panda_grasp_env.agents.learned, panda_grasp_env.perception.heightmap\n"
        "print(json.dumps({n: u.find_spec(n) is not None for n in ('agents', 'perception')}))\n"
    )
    done = subprocess.run([sys.executable, "-c", script], cwd=tmp_path, capture_output=True, text=True, timeout=300)
    assert done.returncode == 0, done.stderr[-2000:]
    found = done.stdout.strip().splitlines()[-1]
    if '"agents": true' in found:  # CI installs openai-agents beside the project in a later step
        pytest.skip("another package provides 'agents' here")
    assert found == '{"agents": false, "perception": false}'
