"""Minari datasets read as data: nothing a dataset's files say is imported or run.

A Minari dataset records the env that made it as a Gymnasium ``EnvSpec`` (JSON: id, ``entry_point``,
keyword arguments, wrappers).  Minari's own ``recover_environment`` hands that spec to ``gymnasium.make``,
which imports and calls whatever ``entry_point`` names -- so a dataset someone else wrote could run any
code.  Minari even does so while *loading* a dataset whose metadata lacks its spaces.  This module reads
``metadata.json`` first and refuses such a dataset; ``recorded_env`` rebuilds the env from this project's
own registration of the recorded id, after checking that the id is one of ours.
"""

from __future__ import annotations

from pathlib import Path
from typing import Any

import gymnasium as gym
import numpy as np

from panda_grasp_env.agents.learning.policy_files import MAX_SPACE_ELEMENTS, MAX_SPACE_KEYS
from panda_grasp_env.geometry import is_count
from panda_grasp_env.registration import ENTRY_POINT, ENV_IDS
from panda_grasp_env.tooling.reading import parse_json, read_json

#: The largest ``metadata.json`` read (bytes): spaces and specs are small; a Box's bounds are listed in full.
MAX_METADATA_BYTES = 16 << 20
#: The most episodes or steps a dataset's metadata may count.
MAX_DATASET_COUNT = 10**9


#: ``gymnasium.make``'s own parameters: an env spec's keyword arguments may not name them.
MAKE_PARAMETERS = frozenset({"id", "max_episode_steps", "autoreset", "apply_api_compatibility", "disable_env_checker"})


def dataset_metadata(folder: Path | str) -> dict[str, Any]:
    """The checked ``metadata.json`` of the Minari dataset whose data folder is ``folder`` (``.../<id>/data``):
    ``ValueError`` naming the file unless it is a bounded JSON mapping holding its observation and action spaces
    (else Minari builds the env to learn them) and any env spec names one of this project's ids."""
    path = Path(folder) / "metadata.json"
    metadata = read_json(path, MAX_METADATA_BYTES)
    if not isinstance(metadata, dict):
        raise ValueError(f"{path} is not a Minari metadata mapping")
    for key in ("observation_space", "action_space"):
        if not isinstance(metadata.get(key), str):
            raise ValueError(
                f"{path} lacks its {key}: Minari would build the recorded env to learn it, and this "
                f"project builds no env a dataset describes"
            )
        # A space nested deeper than any of ours is refused by the reader; one whose counts would overflow or
        # whose elements, over all its parts, would not fit in memory, here: before Minari allocates it.
        check_minari_space(parse_json(metadata[key], f"{path}: {key}"), f"{path}: {key}")
    for key in ("total_episodes", "total_steps"):
        count = metadata.get(key)
        if count is not None and (not is_count(count) or not 0 <= count <= MAX_DATASET_COUNT):
            raise ValueError(
                f"{path}: {key} must be a whole number from 0 to {MAX_DATASET_COUNT}, got {str(count)[:40]}"
            )
    for key in ("env_spec", "eval_env_spec"):
        if metadata.get(key) is not None:
            env_spec(metadata, key, path)
    return metadata


def check_minari_space(space: Any, where: str) -> None:
    """``ValueError`` naming ``where`` unless ``space`` is a Minari space description (``serialize_space``) of
    this project's kinds whose counts fit an int32 and whose elements, over all its parts, number at most
    ``MAX_SPACE_ELEMENTS``."""
    total = 0

    def visit(node: Any, field: str) -> None:
        nonlocal total
        kind = node.get("type") if isinstance(node, dict) else None
        if kind in ("Dict", "Tuple"):
            parts = node.get("subspaces")
            parts = list(parts.values()) if kind == "Dict" and isinstance(parts, dict) else parts
            if not isinstance(parts, list) or len(parts) > MAX_SPACE_KEYS:
                raise ValueError(f"{where}: {field} must hold at most {MAX_SPACE_KEYS} subspaces")
            for index, part in enumerate(parts):
                visit(part, f"{field}.{index}")
            return
        if kind == "Box":
            sizes = node.get("shape")
        elif kind == "MultiBinary":
            sizes = node.get("n") if isinstance(node.get("n"), list) else [node.get("n")]
        elif kind == "Discrete":
            sizes, n, start = [1], node.get("n"), node.get("start", 0)
            if not (is_count(n) and 1 <= n < 2**31 and isinstance(start, int) and abs(start) < 2**31):
                raise ValueError(f"{where}: {field} Discrete n and start must be int32 whole numbers, got {n!r:.40}")
        elif kind == "MultiDiscrete":
            sizes = [len(node.get("nvec") or [])]
            if not all(is_count(n) and n < 2**31 for n in node.get("nvec") or []):
                raise ValueError(f"{where}: {field} MultiDiscrete nvec must be int32 counts")
        else:
            raise ValueError(f"{where}: {field} is not a space of a kind this project records, got {str(kind)[:40]}")
        if not isinstance(sizes, list) or len(sizes) > 8 or not all(is_count(n) for n in sizes):
            raise ValueError(f"{where}: {field} {kind} shape must be at most 8 whole numbers")
        total += int(np.prod(sizes, dtype=object))
        if total > MAX_SPACE_ELEMENTS:
            raise ValueError(f"{where}: its spaces hold more than {MAX_SPACE_ELEMENTS} elements in all")

    visit(space, "space")


def env_spec(metadata: dict[str, Any], key: str, source: Path | str) -> tuple[str, dict[str, Any], int | None]:
    """(id, keyword arguments, max_episode_steps) of the env spec ``metadata[key]`` records, checked: the id
    must be one this project registers, with this project's entry point and no extra wrappers."""
    spec = parse_json(metadata[key], f"{source}: {key}") if isinstance(metadata[key], str) else None
    if not isinstance(spec, dict):
        raise ValueError(f"{source}: {key} is not a JSON env spec")
    env_id, entry_point = spec.get("id"), spec.get("entry_point")
    if not isinstance(env_id, str) or env_id not in ENV_IDS:
        raise ValueError(
            f"{source}: {key} records env id {env_id!r}, not one of this project's "
            f"({sorted(ENV_IDS)}); this project builds no other env from a dataset"
        )
    if entry_point != ENTRY_POINT:
        raise ValueError(
            f"{source}: {key} gives {env_id} the entry point {entry_point!r}, not this project's "
            f"{ENTRY_POINT!r}: the dataset has been altered"
        )
    if spec.get("additional_wrappers"):
        raise ValueError(
            f"{source}: {key} adds wrappers to {env_id} ({spec['additional_wrappers']!r}); this "
            f"project applies none a dataset names"
        )
    kwargs, steps = spec.get("kwargs") or {}, spec.get("max_episode_steps")
    if not isinstance(kwargs, dict) or not all(isinstance(k, str) for k in kwargs):
        raise ValueError(f"{source}: {key} keyword arguments must be a mapping, got {kwargs!r}")
    taken = sorted(set(kwargs) & MAKE_PARAMETERS)
    if taken:
        raise ValueError(f"{source}: {key} keyword arguments {taken} are gymnasium.make's own, not the env's")
    if steps is not None and (not is_count(steps) or steps < 1):
        raise ValueError(f"{source}: {key} max_episode_steps must be a positive int, got {steps!r}")
    return env_id, kwargs, steps


def open_dataset(folder: Path | str) -> Any:
    """The ``minari.MinariDataset`` in data folder ``folder``, once ``dataset_metadata`` has checked it."""
    import minari

    dataset_metadata(folder)
    try:
        return minari.MinariDataset(Path(folder))
    except (AssertionError, KeyError, TypeError, ValueError, OSError) as error:
        raise ValueError(f"cannot read the Minari dataset in {folder}: {error}") from None


def recorded_env(dataset: Any) -> gym.Env:
    """The env that recorded ``dataset`` (a ``minari.MinariDataset``), built from this project's registration
    of the id its metadata records, with the recorded options (which the env checks like any others)."""
    folder = Path(dataset.storage._data_path)  # Minari keeps no public name for it
    metadata = dataset_metadata(folder)
    if metadata.get("env_spec") is None:
        raise ValueError(f"{folder / 'metadata.json'} records no env spec to replay in")
    env_id, kwargs, steps = env_spec(metadata, "env_spec", folder / "metadata.json")
    return gym.make(env_id, **kwargs, **({} if steps is None else {"max_episode_steps": steps}))
