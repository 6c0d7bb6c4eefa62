"""Policies as data: weights in safetensors, the class and its constructor arguments in JSON.

``save_policy(policy, folder / "policy")`` writes ``policy.safetensors`` and ``policy.json``;
``load_policy(folder / "policy")`` builds the policy again without unpickling anything: its class comes from
``policy_classes()`` (this project's heightmap policy and the SB3 policies of the algorithms ``train.py``
runs), the classes among its arguments (activation, optimiser, feature extractor) from
``ARGUMENT_CLASSES``, spaces from their JSON description, and the weights are checked against the digest
the JSON records.  A name outside the allow-lists is refused, never imported.

An SB3 ``.zip`` (``policy.save``) is a pickle: loading one runs whatever code it holds.  ``export_sb3`` writes
one for SB3 users; ``load_sb3`` reads one only with ``trust=True``.
"""

from __future__ import annotations

import json
from functools import cache
from pathlib import Path
from typing import Any

import gymnasium as gym
import numpy as np

from panda_grasp_env.tooling.runs import atomic_path, sha256, write_json

#: The file format written by ``save_policy``; ``load_policy`` refuses others.
FORMAT = 1


def class_name(cls: type) -> str:
    """``module:QualifiedName``: how policy files name a class."""
    return f"{cls.__module__}:{cls.__qualname__}"


@cache
def policy_classes() -> dict[str, type]:
    """The policy classes a policy file may name: the heightmap Q-policy and every SB3 policy alias
    (``MlpPolicy``, ``MultiInputPolicy``, ...) of the algorithms ``train.py`` runs."""
    from sb3_contrib import TQC
    from stable_baselines3 import PPO, SAC

    from panda_grasp_env.agents.heightmap_policy import HeightmapQPolicy

    classes = [HeightmapQPolicy]
    for algo in (SAC, TQC, PPO):
        classes.extend(algo.policy_aliases.values())
    return {class_name(cls): cls for cls in classes}


@cache
def argument_classes() -> dict[str, type]:
    """The classes a policy's constructor arguments may name (activations, optimisers, feature extractors)."""
    import torch as th
    from stable_baselines3.common import torch_layers

    nn, optim = th.nn, th.optim
    classes = (
        nn.ReLU, nn.Tanh, nn.ELU, nn.LeakyReLU, nn.SiLU, nn.GELU, nn.Sigmoid, nn.Identity,
        optim.Adam, optim.AdamW, optim.SGD, optim.RMSprop,
        torch_layers.FlattenExtractor, torch_layers.CombinedExtractor, torch_layers.NatureCNN,
    )  # fmt: skip
    return {class_name(cls): cls for cls in classes}


def _allowed(name: Any, table: dict[str, type], what: str, source: Path) -> type:
    if not isinstance(name, str) or name not in table:
        raise ValueError(f"{source}: {what} {name!r} is not one this project loads; allowed: {sorted(table)}")
    return table[name]


# --- spaces ------------------------------------------------------------------------------------------


def _bound(values: np.ndarray) -> Any:
    """A Box bound as JSON: one number when every entry is the same, else nested lists."""
    flat = values.ravel()
    if flat.size and np.all(flat == flat[0]):
        return flat[0].item()
    return values.tolist()


def space_to_json(space: gym.Space) -> dict[str, Any]:
    """A ``Box``, ``Discrete``, ``MultiDiscrete``, ``MultiBinary`` or ``Dict`` space as a JSON mapping."""
    if isinstance(space, gym.spaces.Box):
        return {"Box": {"low": _bound(space.low), "high": _bound(space.high), "shape": list(space.shape),
                        "dtype": np.dtype(space.dtype).name}}  # fmt: skip
    if isinstance(space, gym.spaces.Discrete):
        return {"Discrete": {"n": int(space.n), "start": int(space.start)}}
    if isinstance(space, gym.spaces.MultiDiscrete):
        return {"MultiDiscrete": {"nvec": space.nvec.tolist(), "start": space.start.tolist()}}
    if isinstance(space, gym.spaces.MultiBinary):
        return {"MultiBinary": {"n": np.asarray(space.n).tolist()}}
    if isinstance(space, gym.spaces.Dict):
        return {"Dict": {key: space_to_json(sub) for key, sub in space.spaces.items()}}
    raise ValueError(f"cannot describe a {type(space).__name__} space in a policy file")


def space_from_json(description: Any) -> gym.Space:
    """The space ``space_to_json`` described; ``ValueError`` for anything else."""
    if not isinstance(description, dict) or len(description) != 1:
        raise ValueError(f"not a space description: {description!r}")
    (kind, fields), = description.items()  # fmt: skip
    try:
        if kind == "Box":
            dtype, shape = np.dtype(fields["dtype"]), tuple(fields["shape"])
            low, high = (np.broadcast_to(np.asarray(fields[k], dtype), shape).copy() for k in ("low", "high"))
            return gym.spaces.Box(low, high, shape, dtype)
        if kind == "Discrete":
            return gym.spaces.Discrete(int(fields["n"]), start=int(fields["start"]))
        if kind == "MultiDiscrete":
            return gym.spaces.MultiDiscrete(fields["nvec"], start=fields["start"])
        if kind == "MultiBinary":
            return gym.spaces.MultiBinary(fields["n"])
        if kind == "Dict":
            return gym.spaces.Dict({key: space_from_json(sub) for key, sub in fields.items()})
    except (KeyError, TypeError, ValueError) as error:
        raise ValueError(f"malformed {kind} space description {fields!r}: {error}") from None
    raise ValueError(f"unknown space kind {kind!r}")


# --- constructor arguments ------------------------------------------------------------------------------


def _encode(value: Any, key: str) -> Any:
    if isinstance(value, gym.Space):
        return {"__space__": space_to_json(value)}
    if isinstance(value, type):
        name = class_name(value)
        if name not in argument_classes():
            raise ValueError(f"argument {key}: class {name} is not one policy files may name")
        return {"__class__": name}
    if isinstance(value, dict):
        return {str(k): _encode(v, f"{key}.{k}") for k, v in value.items()}
    if isinstance(value, (list, tuple)):
        return [_encode(v, key) for v in value]
    if isinstance(value, np.generic):
        return value.item()
    if value is None or isinstance(value, (bool, int, float, str)):
        return value
    raise ValueError(f"argument {key}: cannot store a {type(value).__name__} in a policy file")


def _decode(value: Any, source: Path) -> Any:
    if isinstance(value, dict):
        if set(value) == {"__space__"}:
            return space_from_json(value["__space__"])
        if set(value) == {"__class__"}:
            return _allowed(value["__class__"], argument_classes(), "argument class", source)
        return {k: _decode(v, source) for k, v in value.items()}
    if isinstance(value, list):
        return [_decode(v, source) for v in value]
    return value


# --- files ----------------------------------------------------------------------------------------------


def policy_paths(stem: Path | str) -> tuple[Path, Path]:
    """(``<stem>.json``, ``<stem>.safetensors``)."""
    stem = Path(stem)
    return stem.with_name(stem.name + ".json"), stem.with_name(stem.name + ".safetensors")


def constructor_arguments(policy: Any) -> dict[str, Any]:
    """What rebuilds ``policy`` (SB3's ``_get_constructor_parameters``), with ``share_features_extractor``,
    which SB3's SAC / TQC policies leave out: without it one CNN shared by actor and critics is rebuilt as
    separate ones, and the weights no longer fit."""
    arguments = dict(policy._get_constructor_parameters())
    if hasattr(policy, "share_features_extractor"):
        arguments.setdefault("share_features_extractor", policy.share_features_extractor)
    return arguments


def save_policy(policy: Any, stem: Path | str) -> None:
    """Write ``<stem>.safetensors`` (the weights) and ``<stem>.json`` (class, arguments, weights digest),
    each through a temporary file and a rename; the JSON last, so it only ever names complete weights."""
    from safetensors.torch import save_model

    description, weights = policy_paths(stem)
    arguments = {k: v for k, v in constructor_arguments(policy).items() if k != "lr_schedule"}
    name = class_name(type(policy))
    if name not in policy_classes():
        raise ValueError(f"policy class {name} is not one policy files may name")
    encoded = _encode(arguments, "arguments")
    with atomic_path(weights) as tmp:
        save_model(policy, str(tmp))
    write_json(description, {"format": FORMAT, "policy_class": name, "arguments": encoded,
                             "weights_sha256": sha256(weights)})  # fmt: skip


def load_policy(stem: Path | str) -> Any:
    """The policy ``save_policy`` wrote at ``stem``, on the CPU, in evaluation mode; ``ValueError`` naming the
    file for an unknown format, a class outside the allow-lists, or weights that are not the ones recorded."""
    from safetensors.torch import load_model
    from stable_baselines3.common.policies import BasePolicy

    description, weights = policy_paths(stem)
    try:
        facts = json.loads(description.read_text())
    except (OSError, json.JSONDecodeError) as error:
        raise ValueError(f"cannot read policy file {description}: {error}") from None
    if not isinstance(facts, dict) or facts.get("format") != FORMAT:
        raise ValueError(f"{description} is not a policy file of format {FORMAT}")
    policy_class = _allowed(facts.get("policy_class"), policy_classes(), "policy class", description)
    if not weights.is_file() or sha256(weights) != facts.get("weights_sha256"):
        raise ValueError(f"{weights} is missing or is not the weights {description} records (SHA-256 differs)")
    arguments = _decode(facts.get("arguments"), description)
    if not isinstance(arguments, dict):
        raise ValueError(f"{description}: arguments must be a mapping")
    try:
        policy = policy_class(**arguments, lr_schedule=BasePolicy._dummy_schedule)
        load_model(policy, str(weights), strict=True, device="cpu")
    except Exception as error:  # arguments of another version, tensors of other shapes: say which files
        raise ValueError(f"cannot build the policy of {description} with {weights.name}: {error}") from error
    policy.set_training_mode(False)
    return policy


def export_sb3(policy: Any, path: Path | str) -> Path:
    """The policy in SB3's own format (what ``policy.save`` writes, with ``constructor_arguments``), for SB3
    users: ``type(policy).load(path)`` reads it back; atomic."""
    import torch

    path = Path(path)
    with atomic_path(path) as tmp:
        torch.save({"state_dict": policy.state_dict(), "data": constructor_arguments(policy)}, str(tmp))
    return path


def load_sb3(path: Path | str, policy_class: str, trust: bool = False) -> Any:
    """A policy SB3 saved (``policy.save``).  Such a file is a pickle and loading it runs any code it holds,
    so this refuses unless ``trust=True``; ``policy_class`` must still be one of ``policy_classes()``."""
    path = Path(path)
    cls = _allowed(policy_class, policy_classes(), "policy class", path)
    if not trust:
        raise ValueError(f"{path} is an SB3 pickle (loading it runs any code it holds); load it only if you "
                         f"trust where it came from, with trust=True")  # fmt: skip
    try:
        return cls.load(str(path), device="cpu")
    except Exception as error:  # a truncated zip, a class that changed shape: say which file
        raise ValueError(f"cannot load {path}: {error}") from error
