"""MkDocs hook: a source tree laid out as the package installs, for the API reference.

``agents/`` and ``perception/`` install as ``panda_grasp_env.agents`` and ``panda_grasp_env.perception``
(pyproject's package-dir); griffe reads sources by path, so it is given ``build/api-src/panda_grasp_env``:
links to ``panda_grasp_env/``'s entries plus ``agents`` and ``perception``."""

from __future__ import annotations

import shutil
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
TREE = ROOT / "build" / "api-src" / "panda_grasp_env"


def on_startup(**kwargs: object) -> None:
    shutil.rmtree(TREE, ignore_errors=True)
    TREE.mkdir(parents=True)
    for entry in (ROOT / "panda_grasp_env").iterdir():
        if entry.name != "__pycache__":
            (TREE / entry.name).symlink_to(entry)
    for folder in ("agents", "perception"):
        (TREE / folder).symlink_to(ROOT / folder)
