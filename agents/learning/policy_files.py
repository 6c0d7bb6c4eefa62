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

from functools import cache
from pathlib import Path
from typing import Any

import gymnasium as gym
import numpy as np

from panda_grasp_env.geometry import is_count
from panda_grasp_env.tooling.reading import parse_json, read_json
from panda_grasp_env.tooling.runs import atomic_path, sha256, write_json

#: The file format written by ``save_policy``; ``load_policy`` refuses others.
FORMAT = 1

# Limits ``load_policy`` checks before it allocates anything (a policy file is data someone else may have
# written; the largest shipped policy has 4.5 M parameters, 18 MB of weights and a 3 kB policy.json).
#: Largest policy.json, in bytes.
MAX_DESCRIPTION_BYTES = 1 << 20
#: Deepest nesting of lists and mappings in policy.json.
MAX_DEPTH = 16
#: Largest safetensors file, in bytes.
MAX_WEIGHTS_BYTES = 256 << 20
#: Largest whole number among the constructor arguments (layer widths, channels, critics, rotations).
MAX_WIDTH = 4096
#: Most entries in one list or mapping among the constructor arguments (layers of a ``net_arch`` ...).
MAX_ENTRIES = 32
#: Tighter limits on arguments that multiply whole networks (SB3 defaults to 2 critics, TQC's paper used 5).
ARGUMENT_LIMITS = {"n_critics": 10}
#: Most parameters and buffer elements a policy may have (counted on PyTorch's meta device, which allocates
#: nothing): 256 MB of float32.
MAX_PARAMETERS = 64_000_000
#: Most elements of the spaces of one description (a Box, or all of a Dict's together), and most sub-spaces
#: of a Dict space.
MAX_SPACE_ELEMENTS = 1 << 22
MAX_SPACE_KEYS = 64
#: The keys of policy.json, and the dtype (safetensors' name) of every weight; the longest safetensors header.
DESCRIPTION_KEYS = ("format", "policy_class", "arguments", "weights_sha256")
WEIGHT_DTYPE, MAX_HEADER_BYTES = "F32", 1 << 20
#: The dtypes a Box space may have.
SPACE_DTYPES = ("uint8", "int8", "int16", "int32", "int64", "float16", "float32", "float64", "bool")


def class_name(cls: type) -> str:
    """How policy files name a class: by the name the class itself declares (``policy_file_name``: this
    project's policies, whose modules may move), else ``module:QualifiedName``."""
    return vars(cls).get("policy_file_name") or f"{cls.__module__}:{cls.__qualname__}"


@cache
def policy_classes() -> dict[str, type]:
    """The policy classes a policy file may name: the heightmap Q-policy and every SB3 policy alias
    (``MlpPolicy``, ``MultiInputPolicy``, ...) of the algorithms ``train.py`` runs."""
    from sb3_contrib import TQC
    from stable_baselines3 import PPO, SAC

    from panda_grasp_env.agents.learning.heightmap_policy import HeightmapQPolicy

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
        nn.ReLU,
        nn.Tanh,
        nn.ELU,
        nn.LeakyReLU,
        nn.SiLU,
        nn.GELU,
        nn.Sigmoid,
        nn.Identity,
        optim.Adam,
        optim.AdamW,
        optim.SGD,
        optim.RMSprop,
        torch_layers.FlattenExtractor,
        torch_layers.CombinedExtractor,
        torch_layers.NatureCNN,
    )
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
        return {
            "Box": {
                "low": _bound(space.low),
                "high": _bound(space.high),
                "shape": list(space.shape),
                "dtype": np.dtype(space.dtype).name,
            }
        }
    if isinstance(space, gym.spaces.Discrete):
        return {"Discrete": {"n": int(space.n), "start": int(space.start)}}
    if isinstance(space, gym.spaces.MultiDiscrete):
        return {"MultiDiscrete": {"nvec": space.nvec.tolist(), "start": space.start.tolist()}}
    if isinstance(space, gym.spaces.MultiBinary):
        return {"MultiBinary": {"n": np.asarray(space.n).tolist()}}
    if isinstance(space, gym.spaces.Dict):
        return {"Dict": {key: space_to_json(sub) for key, sub in space.spaces.items()}}
    raise ValueError(f"cannot describe a {type(space).__name__} space in a policy file")


def _whole(value: Any, field: str, low: int, high: int) -> int:
    if not is_count(value) or not low <= value <= high:
        raise ValueError(f"{field} must be a whole number from {low} to {high}, got {_short(value)}")
    return value


def _short(value: Any) -> str:
    text = repr(value)
    return text if len(text) <= 80 else text[:77] + "..."


def declared_elements(description: Any) -> int:
    """The elements the spaces of ``description`` (``space_to_json``'s form) would allocate in all, read from
    their shapes alone: a Box's or MultiBinary's product of sizes, one for any other space, the sum over a
    Dict's.  Malformed parts count one: ``space_from_json`` names them."""
    if not isinstance(description, dict) or len(description) != 1:
        return 1
    ((kind, fields),) = description.items()
    if not isinstance(fields, dict):
        return 1
    if kind == "Dict":
        return sum(declared_elements(sub) for sub in fields.values())
    sizes = fields.get("shape") if kind == "Box" else fields.get("n") if kind == "MultiBinary" else None
    sizes = [sizes] if is_count(sizes) else sizes
    if isinstance(sizes, list) and all(is_count(n) for n in sizes):
        return int(np.prod([max(n, 1) for n in sizes], dtype=object))
    return 1


def space_from_json(description: Any, field: str = "space") -> gym.Space:
    """The space ``space_to_json`` described; ``ValueError`` naming ``field`` (where the description sits) for
    anything else, and for shapes, counts or dtypes beyond ``MAX_SPACE_ELEMENTS`` (one space, and all of a
    Dict's together), ``MAX_SPACE_KEYS`` and ``SPACE_DTYPES``, before anything is allocated."""
    total = declared_elements(description)
    if total > MAX_SPACE_ELEMENTS:
        raise ValueError(f"{field}: its spaces hold {total} elements in all, more than {MAX_SPACE_ELEMENTS}")
    return _space_from_json(description, field)


def _space_from_json(description: Any, field: str) -> gym.Space:
    if not isinstance(description, dict) or len(description) != 1:
        raise ValueError(f"{field}: not a space description: {_short(description)}")
    ((kind, fields),) = description.items()
    field = f"{field}.{kind}"
    if kind not in ("Box", "Discrete", "MultiDiscrete", "MultiBinary", "Dict"):
        raise ValueError(f"{field}: unknown space kind {kind!r}")
    if not isinstance(fields, dict):
        raise ValueError(f"{field}: malformed {kind} space description {_short(fields)}")
    try:
        if kind == "Box":
            shape = fields["shape"]
            if not isinstance(shape, list) or len(shape) > 8:
                raise ValueError(f"{field}.shape must be a list of at most 8 sizes, got {_short(shape)}")
            shape = tuple(_whole(n, f"{field}.shape", 1, MAX_SPACE_ELEMENTS) for n in shape)
            if int(np.prod(shape)) > MAX_SPACE_ELEMENTS:
                raise ValueError(f"{field}.shape {list(shape)} has more than {MAX_SPACE_ELEMENTS} elements")
            if fields["dtype"] not in SPACE_DTYPES:
                raise ValueError(f"{field}.dtype must be one of {list(SPACE_DTYPES)}, got {_short(fields['dtype'])}")
            dtype = np.dtype(fields["dtype"])
            bounds = []
            for key in ("low", "high"):
                bound = np.asarray(fields[key])
                if bound.dtype.kind not in "biuf" or bound.size not in (1, int(np.prod(shape))):
                    raise ValueError(f"{field}.{key} must be a number or numbers of shape {list(shape)}")
                bounds.append(np.broadcast_to(bound.astype(dtype), shape).copy())
            return gym.spaces.Box(bounds[0], bounds[1], shape, dtype)
        if kind == "Discrete":
            n = _whole(fields["n"], f"{field}.n", 1, 2**31 - 1)
            return gym.spaces.Discrete(n, start=_whole(fields["start"], f"{field}.start", -(2**31), 2**31 - 1))
        if kind == "MultiDiscrete":
            nvec, start = fields["nvec"], fields["start"]
            if not isinstance(nvec, list) or not isinstance(start, list) or not 1 <= len(nvec) <= MAX_SPACE_KEYS:
                raise ValueError(f"{field}.nvec and .start must be lists of 1 to {MAX_SPACE_KEYS} counts")
            nvec = [_whole(n, f"{field}.nvec", 1, 2**31 - 1) for n in nvec]
            start = [_whole(n, f"{field}.start", -(2**31), 2**31 - 1) for n in start]
            return gym.spaces.MultiDiscrete(nvec, start=start)
        if kind == "MultiBinary":
            n = fields["n"]
            sizes = n if isinstance(n, list) else [n]
            sizes = [_whole(k, f"{field}.n", 1, MAX_SPACE_ELEMENTS) for k in sizes]
            if not sizes or len(sizes) > 8 or int(np.prod(sizes)) > MAX_SPACE_ELEMENTS:
                raise ValueError(f"{field}.n must be 1 to 8 sizes of at most {MAX_SPACE_ELEMENTS} elements in all")
            return gym.spaces.MultiBinary(sizes if isinstance(n, list) else sizes[0])
        if len(fields) > MAX_SPACE_KEYS:
            raise ValueError(f"{field} has {len(fields)} sub-spaces, more than {MAX_SPACE_KEYS}")
        return gym.spaces.Dict({key: _space_from_json(sub, f"{field}.{key}") for key, sub in fields.items()})
    except KeyError as error:
        raise ValueError(f"{field}: malformed {kind} space description, no {error}") from None
    except (TypeError, OverflowError, AssertionError) as error:
        raise ValueError(f"{field}: malformed {kind} space description {_short(fields)}: {error}") from None


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


def _decode(value: Any, source: Path, field: str = "arguments") -> Any:
    """Constructor arguments from their JSON form: spaces and allowed classes rebuilt, every whole number at
    most ``MAX_WIDTH`` and every list or mapping at most ``MAX_ENTRIES`` long (``ValueError`` naming the field)."""
    if isinstance(value, dict):
        if set(value) == {"__space__"}:
            try:
                return space_from_json(value["__space__"], field)
            except ValueError as error:
                raise ValueError(f"{source}: {error}") from None
        if set(value) == {"__class__"}:
            return _allowed(value["__class__"], argument_classes(), "argument class", source)
        if len(value) > MAX_ENTRIES:
            raise ValueError(f"{source}: {field} has {len(value)} entries, more than {MAX_ENTRIES}")
        for key, limit in ARGUMENT_LIMITS.items():
            if isinstance(value.get(key), int) and value[key] > limit:
                raise ValueError(f"{source}: {field}.{key} is {value[key]}, more than the {limit} this project loads")
        return {k: _decode(v, source, f"{field}.{k}") for k, v in value.items()}
    if isinstance(value, list):
        if len(value) > MAX_ENTRIES:
            raise ValueError(f"{source}: {field} has {len(value)} entries, more than {MAX_ENTRIES}")
        decoded = [_decode(v, source, f"{field}[{i}]") for i, v in enumerate(value)]
        if all(is_count(v) for v in decoded):  # layer widths: a quick floor
            least = sum(a * b for a, b in zip(decoded, decoded[1:]))
            if least > MAX_PARAMETERS:
                raise ValueError(
                    f"{source}: {field} {decoded} makes layers of at least {least} parameters, more "
                    f"than the {MAX_PARAMETERS} this project loads"
                )
        return decoded
    if is_count(value) and abs(value) > MAX_WIDTH:
        raise ValueError(f"{source}: {field} is {_short(value)}; network sizes and counts stay within {MAX_WIDTH}")
    if isinstance(value, float) and not np.isfinite(value):
        raise ValueError(f"{source}: {field} is {value}, not a finite number")
    return value


def count_parameters(policy_class: type, arguments: dict[str, Any]) -> int:
    """The elements ``policy_class(**arguments)`` would hold, its parameters and its buffers (the heightmap
    policy's rotation grids grow with rotations x grid), built on PyTorch's meta device: shapes without
    storage, so a policy of any size costs nothing to count."""
    from unittest import mock

    import torch as th
    from stable_baselines3.common.policies import BaseModel, BasePolicy

    # SB3 moves each part to ``self.device`` as it builds it (the CPU while no part holds parameters); here
    # every part stays on the meta device.
    with th.device("meta"), mock.patch.object(BaseModel, "device", property(lambda self: th.device("meta"))):
        policy = policy_class(**arguments, lr_schedule=BasePolicy._dummy_schedule)
    return sum(tensor.numel() for tensor in (*policy.parameters(), *policy.buffers()))


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
    write_json(
        description, {"format": FORMAT, "policy_class": name, "arguments": encoded, "weights_sha256": sha256(weights)}
    )


def load_policy(stem: Path | str) -> Any:
    """The policy ``save_policy`` wrote at ``stem``, on the CPU, in evaluation mode; ``ValueError`` naming the
    file (and the field) for malformed JSON, an unknown format, a class outside the allow-lists, a size beyond
    the limits above (checked before anything is allocated), or weights that are not the ones recorded.

    The SHA-256 in policy.json ties the weights to that description, against a swapped or damaged weights
    file; it is no signature: whoever can edit the folder can rewrite both, so the limits and allow-lists,
    not the digest, are what make a folder from elsewhere safe to load."""
    from safetensors.torch import load_model
    from stable_baselines3.common.policies import BasePolicy

    description, weights = policy_paths(stem)
    facts = read_json(description, MAX_DESCRIPTION_BYTES, MAX_DEPTH)
    if not isinstance(facts, dict) or facts.get("format") != FORMAT or isinstance(facts.get("format"), bool):
        raise ValueError(f"{description} is not a policy file of format {FORMAT}")
    unknown = sorted(set(facts) - set(DESCRIPTION_KEYS))
    if unknown:
        raise ValueError(
            f"{description}: unknown key(s) {_short(unknown)}; a policy file holds {list(DESCRIPTION_KEYS)}"
        )
    policy_class = _allowed(facts.get("policy_class"), policy_classes(), "policy class", description)
    if not isinstance(facts.get("arguments"), dict):
        raise ValueError(f"{description}: arguments must be a mapping")
    arguments = _decode(facts["arguments"], description)
    if not weights.is_file():
        raise ValueError(f"{weights} is missing or is not the weights {description} records (no such file)")
    if weights.stat().st_size > MAX_WEIGHTS_BYTES:
        raise ValueError(
            f"{weights} holds {weights.stat().st_size} bytes, more than the {MAX_WEIGHTS_BYTES} a policy's weights may"
        )
    if sha256(weights) != facts.get("weights_sha256"):
        raise ValueError(f"{weights} is missing or is not the weights {description} records (SHA-256 differs)")
    check_weight_dtypes(weights)
    try:
        parameters = count_parameters(policy_class, arguments)
    except Exception as error:  # arguments of another version or of no policy: say which file
        raise ValueError(f"cannot build the policy of {description}: {error}") from None
    if parameters > MAX_PARAMETERS:
        raise ValueError(
            f"{description}: arguments build a policy of {parameters} parameters and buffer elements, more than "
            f"the {MAX_PARAMETERS} this project loads"
        )
    try:
        policy = policy_class(**arguments, lr_schedule=BasePolicy._dummy_schedule)
        load_model(policy, str(weights), strict=True, device="cpu")
    except Exception as error:  # arguments of another version, tensors of other shapes: say which files
        raise ValueError(f"cannot build the policy of {description} with {weights.name}: {error}") from error
    for name, tensor in policy.state_dict().items():
        if tensor.is_floating_point() and not bool(tensor.isfinite().all()):
            raise ValueError(f"{weights}: tensor {name!r} holds NaN or infinite weights")
    policy.set_training_mode(False)
    return policy


def check_weight_dtypes(weights: Path) -> None:
    """``ValueError`` naming ``weights`` and the tensor unless every tensor of the safetensors file is float32
    (``WEIGHT_DTYPE``: what ``save_policy`` writes), read from the file's header before any tensor is."""
    with open(weights, "rb") as handle:
        head = handle.read(8)
        size = int.from_bytes(head, "little") if len(head) == 8 else -1
        if not 0 < size <= MAX_HEADER_BYTES:
            raise ValueError(f"{weights} is not a safetensors file (header of {size} bytes)")
        header = parse_json(handle.read(size).decode("utf-8", errors="replace"), f"{weights} header", 4)
    if not isinstance(header, dict):
        raise ValueError(f"{weights} is not a safetensors file (its header is not a mapping)")
    for name, entry in header.items():
        dtype = entry.get("dtype") if isinstance(entry, dict) else None
        if name != "__metadata__" and dtype != WEIGHT_DTYPE:
            raise ValueError(f"{weights}: tensor {_short(name)} is {_short(dtype)}, not {WEIGHT_DTYPE} (float32)")


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
        raise ValueError(
            f"{path} is an SB3 pickle (loading it runs any code it holds); load it only if you "
            f"trust where it came from, with trust=True"
        )
    try:
        return cls.load(str(path), device="cpu")
    except Exception as error:  # a truncated zip, a class that changed shape: say which file
        raise ValueError(f"cannot load {path}: {error}") from error
