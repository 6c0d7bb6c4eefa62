"""The Franka Panda arm and hand as ``gymnasium-robotics`` ships them (``kitchen_franka/franka_assets``).

The MJCF files are read from the installed package at build time, never copied into this repository;
``scene.build_spec`` then tunes the robot and adds the workcell around it.
"""

from __future__ import annotations

import re
from pathlib import Path

import mujoco


def franka_asset_dir() -> Path:
    """Folder of the Franka MJCF files inside the installed ``gymnasium-robotics``."""
    import importlib.util

    spec = importlib.util.find_spec("gymnasium_robotics")
    if spec is None or spec.origin is None:
        raise ImportError("gymnasium-robotics is required: it ships the Franka Panda model this scene loads")
    folder = Path(spec.origin).parent / "envs" / "assets" / "kitchen_franka" / "franka_assets"
    if not (folder / "chain.xml").is_file():
        raise FileNotFoundError(f"Franka assets not found in the installed gymnasium-robotics: {folder}")
    return folder


def _inner_xml(path: Path) -> str:
    """Contents of a ``<mujocoinclude>`` file without the wrapper tag and comments."""
    text = re.sub(r"<!--.*?-->", "", path.read_text(), flags=re.S)
    match = re.search(r"<mujocoinclude>(.*)</mujocoinclude>", text, flags=re.S)
    if match is None:
        raise ValueError(f"{path} is not a <mujocoinclude> file")
    return match.group(1)


def panda_spec() -> mujoco.MjSpec:
    """The arm and hand with their actuators, as the asset defines them (not yet compiled)."""
    folder = franka_asset_dir()
    assets = _inner_xml(folder / "assets.xml").replace(
        'meshdir="franka_assets/meshes"', f'meshdir="{folder / "meshes"}"'
    )
    xml = (
        "<mujoco model='panda_workcell'>"
        + assets
        + _inner_xml(folder / "actuator.xml")
        + "<worldbody>"
        + _inner_xml(folder / "chain.xml")
        + "</worldbody></mujoco>"
    )
    return mujoco.MjSpec.from_string(xml)
