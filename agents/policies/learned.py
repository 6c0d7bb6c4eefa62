"""Shipped learned policies: load a checkpoint by name and act through the same protocol as every agent.

A checkpoint is a folder ``agents/checkpoints/<name>/`` written by
``python train.py --ship <run folder> --name <name>``::

    policy.safetensors  the policy's weights (no optimiser, no replay buffer): the run's best on validation
    policy.json         its class and constructor arguments, as data (``panda_grasp_env.agents.learning.policy_files``)
    checkpoint.json     env id, evaluation task, policy class, the step it was saved at, and the rules the
                        policy acts by (``PolicyAgent``'s ``ACTING_RULES``, set by ``--ship`` with
                        ``--avoid-failures``, ``--centre-on-faces``, ``--inward-pushes`` or ``--place-where-lacking``)
    config.yaml         the training config
    card.md             the model card: config, seed, steps, wall time, machine, metrics with 95 % CIs
    curve.png           the learning curve; evaluations.jsonl, final.json, meta.json: its data

Loading one unpickles nothing.  A folder laid out the same way with an SB3 ``policy.zip`` instead (a pickle:
loading it runs any code it holds) loads only with ``trust=True``; ``Checkpoint.export_sb3`` writes that zip.
"""

from __future__ import annotations

import dataclasses
from collections.abc import Mapping
from pathlib import Path
from typing import Any

import gymnasium as gym
import numpy as np

from panda_grasp_env.agents.learning.config import TrainConfig, config_from_dict, make_env, observation_transform
from panda_grasp_env.agents.learning.policy_files import export_sb3, load_policy, load_sb3, policy_paths
from panda_grasp_env.agents.policies.policy_agent import ACTING_RULES, PolicyAgent, check_acting_rules
from panda_grasp_env.tooling.extras import require_learning_stack
from panda_grasp_env.tooling.reading import read_json, read_yaml
from panda_grasp_env.tooling.runs import sha256

CHECKPOINTS = Path(__file__).resolve().parents[1] / "checkpoints"
SHIPPED_FILES = (
    "best_policy.json",
    "best_policy.safetensors",
    "best.json",
    "config.yaml",
    "card.md",
    "curve.png",
    "evaluations.jsonl",
    "final.json",
    "meta.json",
)


def available_checkpoints() -> list[str]:
    """Names of the shipped checkpoints."""
    if not CHECKPOINTS.is_dir():
        return []
    return sorted(p.name for p in CHECKPOINTS.iterdir() if (p / "checkpoint.json").is_file())


#: checkpoint.json's keys and their JSON types (``task`` and ``steps`` required); a value of another type
#: (``"avoid_failures": "no"``) is refused, not read by Python's truthiness.
CHECKPOINT_FACTS: dict[str, type | tuple[type, ...]] = {
    "task": str,
    "steps": int,
    "policy_class": str,
    "env_id": str,
    "algo": str,
    "avoid_failures": bool,
    "centre_on_faces": bool,
    "inward_pushes": bool,
    "place_where_lacking": bool,
}
#: Largest checkpoint.json and config.yaml read, in bytes.
MAX_FACTS_BYTES = 64 << 10
MAX_CONFIG_BYTES = 1 << 20


def read_checkpoint_facts(path: Path) -> dict[str, Any]:
    """checkpoint.json, checked: a JSON mapping of ``CHECKPOINT_FACTS`` with exactly their types (``steps`` a
    whole number >= 0); ``ValueError`` naming the file and the key otherwise."""
    facts = read_json(path, MAX_FACTS_BYTES)
    if not isinstance(facts, dict):
        raise ValueError(f"{path} must be a JSON mapping of {list(CHECKPOINT_FACTS)}, got a {type(facts).__name__}")
    unknown = sorted(set(facts) - set(CHECKPOINT_FACTS))
    missing = [k for k in ("task", "steps") if k not in facts]
    if unknown or missing:
        raise ValueError(f"{path}: unknown key(s) {unknown}, missing key(s) {missing}; valid: {list(CHECKPOINT_FACTS)}")
    for key, value in facts.items():
        kind = CHECKPOINT_FACTS[key]
        if not isinstance(value, kind) or (kind is int and isinstance(value, bool)):
            raise ValueError(
                f"{path}: {key} must be a JSON {'boolean' if kind is bool else kind.__name__}, got {value!r:.80}"
            )
    if facts["steps"] < 0:
        raise ValueError(f"{path}: steps must be >= 0, got {facts['steps']}")
    return facts


def read_config(path: Path) -> TrainConfig:
    """A checkpoint's config.yaml (YAML's safe subset, at most ``MAX_CONFIG_BYTES``); ``ValueError`` naming it."""
    raw = read_yaml(path, MAX_CONFIG_BYTES)
    if not isinstance(raw, dict) or not all(isinstance(k, str) for k in raw):
        raise ValueError(f"{path} must be a mapping of training config keys")
    return config_from_dict(raw, str(path))


class Checkpoint:
    """A shipped checkpoint folder (or any folder laid out the same way)."""

    def __init__(self, name_or_path: str | Path, trust: bool = False) -> None:
        """``trust``: also load an SB3 ``policy.zip`` (a pickle) where the folder has no ``policy.json``.
        ``ModuleNotFoundError`` naming the ``learn`` extra where it is not installed (its config names SB3
        classes, checked on reading)."""
        require_learning_stack(f"learned agent {Path(name_or_path).name}")
        path = Path(name_or_path)
        if not (path / "checkpoint.json").is_file():
            path = CHECKPOINTS / str(name_or_path)
        if not (path / "checkpoint.json").is_file():
            raise ValueError(f"unknown checkpoint {str(name_or_path)!r}; available: {available_checkpoints()}")
        self.path = path
        self.name = path.name
        self.meta = read_checkpoint_facts(path / "checkpoint.json")
        self.config: TrainConfig = read_config(path / "config.yaml")
        self.trust = trust
        if not policy_paths(path / "policy")[0].is_file() and not (path / "policy.zip").is_file():
            raise ValueError(f"checkpoint {self.name} is incomplete: policy.json missing in {path}")

    @property
    def task(self) -> str:
        return self.meta["task"]

    @property
    def acting(self) -> dict[str, bool]:
        """The rules the policy acts by as shipped (``ACTING_RULES``, each on or off): choices made on selection
        seeds, not part of its training."""
        return {rule: self.meta.get(rule, False) for rule in ACTING_RULES}

    def load_policy(self) -> Any:
        """The policy, from policy.json + policy.safetensors; from an SB3 policy.zip only if ``trust``."""
        stem = self.path / "policy"
        try:
            if policy_paths(stem)[0].is_file():
                return load_policy(stem)
            return load_sb3(self.path / "policy.zip", self.meta.get("policy_class"), trust=self.trust)
        except ValueError as error:
            raise ValueError(f"checkpoint {self.name}: {error}") from None

    def export_sb3(self, path: Path | str) -> Path:
        """The policy as an SB3 ``.zip`` (``type(policy).load(path)`` reads it back), for SB3 users."""
        return export_sb3(self.load_policy(), path)

    def provenance(self) -> dict[str, Any]:
        """Where this checkpoint's weights came from: its folder, the training step they were saved at and the
        SHA-256 of its weights (a fine-tuning run records it: the name alone may be shipped again)."""
        weights = policy_paths(self.path / "policy")[1]
        return {
            "path": str(self.path.resolve()),
            "steps": self.meta["steps"],
            "policy_sha256": sha256(weights if weights.is_file() else self.path / "policy.zip"),
        }

    def make_env(self, **options: Any) -> gym.Env:
        """The env the policy was trained on (raw observations; the agent transforms them), with ``options``
        (``gymnasium.make`` keyword arguments) on top of its training ``env_kwargs``."""
        return make_env(dataclasses.replace(self.config, env_kwargs={**self.config.env_kwargs, **options}))


def observation_mismatch(space: gym.Space, observation: Any) -> str | None:
    """How a (transformed) observation's shapes differ from what ``space`` expects, or None if they match.

    An image the policy sees channel-first (C, H, W) may come channel-last (H, W, C), as cameras give it:
    SB3's ``predict`` transposes it, as its ``VecTransposeImage`` did in training."""
    from stable_baselines3.common.preprocessing import is_image_space

    def fits(box: gym.Space, shape: tuple[int, ...]) -> bool:
        channel_last = (*box.shape[1:], box.shape[0]) if is_image_space(box, check_channels=False) else None
        return shape in (box.shape, channel_last)

    if isinstance(space, gym.spaces.Dict):
        shapes = {k: np.shape(v) for k, v in observation.items()} if isinstance(observation, dict) else None
        wanted: Any = {k: s.shape for k, s in space.spaces.items()}
        match = shapes is not None and shapes.keys() == wanted.keys()
        match = match and all(fits(space.spaces[k], shapes[k]) for k in wanted)
    else:
        shapes, wanted = np.shape(observation), space.shape
        match = fits(space, shapes)
    return None if match else f"expects observations {wanted}, this env gives {shapes}"


def check_compatible(policy: Any, config: TrainConfig, env: gym.Env, name: str) -> None:
    """``ValueError`` naming the mismatch unless ``env``'s observations (as the policy sees them) and actions have
    the shapes and space the policy was trained on.  Any env id will do: the policy of
    ``PandaGraspClutter-v0`` runs on ``clutter=False, n_objects=1``, or on another id with the same spaces."""
    try:
        seen = observation_transform(config)(env.observation_space.sample(), {})
    except (KeyError, IndexError, TypeError, ValueError):  # not even the layout the transform reads
        seen = None
    mismatch = (
        observation_mismatch(policy.observation_space, seen)
        if seen is not None
        else (
            f"expects observations {policy.observation_space} (after its transform), this env gives "
            f"{env.observation_space}"
        )
    )
    if mismatch:
        raise ValueError(f"checkpoint {name} {mismatch}")
    if policy.action_space != env.action_space:
        raise ValueError(f"checkpoint {name} acts in {policy.action_space}, this env expects {env.action_space}")


class LearnedAgent(PolicyAgent):
    """A shipped policy as an ``Agent``: deterministic actions from the observation, by the rules it was shipped
    with, or as ``acting`` turns them on or off (a heightmap policy's acting rules: see ``PolicyAgent``)."""

    def __init__(
        self,
        checkpoint: str | Path,
        env: gym.Env | None = None,
        acting: Mapping[str, bool] | None = None,
        trust: bool = False,
        grid: tuple[int, int] | None = None,
    ) -> None:
        """``acting``: acting rules turned on or off (``ACTING_RULES``), over those the checkpoint was shipped
        with (``Checkpoint.acting``); ``trust``: the checkpoint may be an SB3 ``policy.zip`` (a pickle: see
        ``Checkpoint``); ``grid``: (rows, columns) of the heightmap a heightmap policy acts on, if not the one
        it was trained on (same resolution: ``HeightmapQPolicy.on_grid``)."""
        check_acting_rules(acting or {})
        self.checkpoint = Checkpoint(checkpoint, trust)
        policy = self.checkpoint.load_policy()
        if grid is not None:
            if not hasattr(policy, "on_grid"):
                raise ValueError(f"checkpoint {self.checkpoint.name}'s policy acts on no heightmap grid to resize")
            policy = policy.on_grid(*grid)
        acting = self.checkpoint.acting | dict(acting or {})
        super().__init__(policy, observation_transform(self.checkpoint.config), self.checkpoint.name, **acting)
        if env is not None:
            check_compatible(policy, self.checkpoint.config, env, self.name)

    def reset(self, observation: Any, info: dict[str, Any]) -> None:
        super().reset(observation, info)
        mismatch = observation_mismatch(self.model.observation_space, self.transform(observation, info))
        if mismatch:
            raise ValueError(f"checkpoint {self.name} cannot act here: it {mismatch}")
