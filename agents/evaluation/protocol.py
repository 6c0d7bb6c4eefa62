"""The benchmark protocol: which agents play which benchmark tasks, on which seeds, with which env options.

An episode is fully determined by its ``EpisodeSpec`` (agent, task, seed, options): the env is reset with the
seed and every agent draws from generators seeded from it, so results repeat bit for bit, in any process, in
any order.  A ``RunProtocol`` is one run's set of them (``evaluate.py``'s agents, tasks, seeds and task options).
The benchmark tasks themselves, their env ids and their quick and full seed counts, are declared in
``benchmarks``.
"""

from __future__ import annotations

import functools
import hashlib
import importlib
import importlib.util
import json
import os
import sys
from collections.abc import Iterable, Mapping
from dataclasses import dataclass, field
from pathlib import Path
from typing import TYPE_CHECKING, Any

import gymnasium as gym

# The built-in planned agents and experts register themselves (``registry``) when their modules are imported.
import panda_grasp_env.agents.policies.experts
import panda_grasp_env.agents.policies.grasping
import panda_grasp_env.agents.policies.learned_physics
import panda_grasp_env.agents.policies.put_in_bin
import panda_grasp_env.agents.policies.structures
import panda_grasp_env.agents.policies.towers  # noqa: F401
from panda_grasp_env.actions import ACTION_MODES
from panda_grasp_env.agents.evaluation.benchmarks import BENCHMARKS
from panda_grasp_env.agents.policies.registry import (
    BASELINES,
    BUILT_IN_AGENTS,
    EXPERTS,
    NAMED_AGENTS,
    BaselineFactory,
)
from panda_grasp_env.env_options import AGENT_OPTIONS
from panda_grasp_env.registration import ENV_IDS, TASKS
from panda_grasp_env.tooling.extras import learning_stack_problem
from panda_grasp_env.tooling.reading import MAX_DOCUMENT_BYTES, read_text
from panda_grasp_env.tooling.runs import apply_key_values

if TYPE_CHECKING:
    from panda_grasp_env.agents.policies.learned import Checkpoint

#: The built-in agents; every shipped checkpoint (``panda_grasp_env.agents.policies.learned.available_checkpoints``)
#: is an agent too, and so is every agent registered by name (``registry.register_agent``).
AGENTS = BUILT_IN_AGENTS
#: What the perception agents (``planned``, ``oracle``) see: RGB-D from both cameras at 640 x 480.
PERCEPTION = {"obs_mode": "rgbd", "cameras": ("overhead", "front"), "image_size": (640, 480)}


def import_modules(names: Iterable[str]) -> None:
    """Import the modules that register tasks and agents from outside the package (``evaluate.py --import``):
    dotted module names, looked up on the Python path and in the current folder, or paths of ``.py`` files.
    ``ValueError`` names one that does not import.  Worker processes call it too, before their first episode."""
    if os.getcwd() not in sys.path:
        sys.path.append(os.getcwd())
    for name in names:
        try:
            if name.endswith(".py"):
                path = Path(name).resolve()
                module_name = path.stem
                if getattr(sys.modules.get(module_name), "__file__", None) == str(path):
                    continue  # imported already: its tasks and agents are registered
                spec = importlib.util.spec_from_file_location(module_name, path)
                if spec is None or spec.loader is None or not path.is_file():
                    raise ImportError(f"no Python file at {path}")
                module = importlib.util.module_from_spec(spec)
                sys.modules[module_name] = module
                try:
                    spec.loader.exec_module(module)
                except BaseException:
                    del sys.modules[module_name]
                    raise
            else:
                importlib.import_module(name)
        except (Exception, SystemExit) as error:  # whatever the module raises at import (sys.exit too): one line
            raise ValueError(f"--import {name}: {type(error).__name__}: {error}") from None


def imported_files(names: Iterable[str]) -> list[dict[str, str]]:
    """What each ``--import`` module ran from: its name, its file's path and the SHA-256 of that file (the
    code that registered tasks and agents from outside the package, which no commit of this repository
    holds).  The modules must be imported already (``import_modules``)."""
    from panda_grasp_env.tooling.runs import sha256

    files = []
    for name in names:
        path = Path(name).resolve() if name.endswith(".py") else Path(getattr(sys.modules[name], "__file__", "") or "")
        digest = sha256(path) if path.is_file() else "not a file"
        files.append({"module": name, "file": str(path), "sha256": digest})
    return files


def code_label(imports: Iterable[str] = ()) -> str:
    """The code an episode record was made by: this repository's commit (``tooling.runs.commit``), and with
    ``--import`` modules the first 12 hex digits of a SHA-256 over theirs (``imported_files``), so that a
    ``--resume`` after one of those files changed redoes its episodes."""
    from panda_grasp_env.tooling.runs import commit

    files = imported_files(imports)
    if not files:
        return commit()
    digest = hashlib.sha256(json.dumps(files, sort_keys=True).encode()).hexdigest()[:12]
    return f"{commit()}+imports-{digest}"


def action_mode_of(env_id: str, options: dict[str, Any]) -> str:
    """The action mode ``gymnasium.make(env_id, **options)`` gets (an explicit option, else the id's task default)."""
    registered = ENV_IDS[env_id][0]
    return options.get("action_mode") or registered.get("action_mode") or TASKS[registered["task"]].default_action_mode


def is_low_level(env_id: str, options: dict[str, Any]) -> bool:
    """Whether that env acts at 25 Hz (the action mode's ``low_level``) rather than through motion primitives."""
    name = action_mode_of(env_id, options)
    return isinstance(name, str) and name in ACTION_MODES and ACTION_MODES[name].low_level


def task_label(env_id: str, env_kwargs: dict[str, Any]) -> str:
    """The ``evaluate.py`` task whose env (id, low-level or not) a policy trained on ``env_id`` plays, else ``env_id``."""
    low_level = is_low_level(env_id, env_kwargs)
    for task, benchmark in BENCHMARKS.items():
        if benchmark.env_id == env_id and is_low_level(benchmark.env_id, benchmark.options) == low_level:
            return task
    return env_id


def all_agents() -> tuple[str, ...]:
    """Built-in agents, the shipped learned checkpoints by name, the phased agents made of them, then the agents
    registered by name (``registry.register_agent``: from ``--import`` modules)."""
    from panda_grasp_env.agents.policies.learned import available_checkpoints
    from panda_grasp_env.agents.policies.phased import PHASED_AGENTS

    return (*AGENTS, *available_checkpoints(), *PHASED_AGENTS, *NAMED_AGENTS)


def baseline(task: str) -> BaselineFactory | None:
    """The planned baseline of benchmark ``task``: the one registered for it, else for the benchmark it is a
    variant of (``Benchmark.variant_of``), else None."""
    return BASELINES.get(task) or BASELINES.get(BENCHMARKS[task].variant_of or "")


def skip_reason(agent: str, task: str) -> str | None:
    """Why ``agent`` does not apply to ``task`` (None if it does)."""
    if agent == "random":
        return None
    if agent == "expert":
        return None if task in EXPERTS else f"no scripted low-level expert is written for {task}"
    if agent in NAMED_AGENTS:
        named = NAMED_AGENTS[agent]
        if task not in named.tasks:
            return f"agent {agent} was registered for {', '.join(named.tasks)}"
        return learning_stack_problem(f"agent {agent}") if named.needs_learning_stack else None
    if agent in AGENTS:
        if is_low_level(BENCHMARKS[task].env_id, BENCHMARKS[task].options):
            return f"the {agent} baselines act through motion primitives; {task} is a low-level ee_delta task"
        if baseline(task) is None:
            return f"no {agent} agent is written for {task}"
        return None
    from panda_grasp_env.agents.policies.phased import PHASED_AGENTS

    if learning_stack_problem("a learned agent") is not None:  # a checkpoint, alone or in phases
        return learning_stack_problem(f"learned agent {agent}")
    if agent in PHASED_AGENTS:
        tasks = PHASED_AGENTS[agent].tasks
        return None if task in tasks else f"the phased agent {agent} plays {', '.join(tasks)}"
    return learned_skip_reason(agent, task)


def learned_skip_reason(agent: str, task: str) -> str | None:
    """Why checkpoint ``agent`` does not play ``task`` (None if it does).

    A checkpoint plays the task it was trained for, and any other benchmark task of the same registered task
    at the same level of action (motion primitives or 25 Hz control) whose env, seen and acted on as the
    checkpoint was trained (``learned_env``), gives the observations and takes the actions its policy does
    (``learned.check_compatible``): a heightmap grasping policy trained on packed layouts plays random heaps
    and single objects too.  Only the benchmark's env is made, never the one the checkpoint was trained on:
    a policy trained on meshes is judged on a block task without the mesh set installed."""
    from panda_grasp_env.agents.policies.learned import Checkpoint

    checkpoint = Checkpoint(agent)
    config = checkpoint.config
    if checkpoint.task == task:
        return None
    trained_for = f"checkpoint {agent} was trained for {checkpoint.task} ({config.env_id})"
    benchmark = BENCHMARKS[task]
    if ENV_IDS[benchmark.env_id][0]["task"] != ENV_IDS[config.env_id][0]["task"]:
        return trained_for
    if is_low_level(benchmark.env_id, benchmark.options) != is_low_level(config.env_id, config.env_kwargs):
        return f"{trained_for}, at the other level of action"
    card = read_text(checkpoint.path / "checkpoint.json", MAX_DOCUMENT_BYTES)
    mismatch = _policy_mismatch(checkpoint.path.resolve(), card, checkpoint.provenance()["policy_sha256"], task)
    return None if mismatch is None else f"{trained_for}; on {task}: {mismatch}"


@functools.cache
def _policy_mismatch(path: Path, card: str, weights: str, task: str) -> str | None:
    """How ``task``'s env for the checkpoint at ``path`` does not fit its policy (observations or actions), or
    None; once per checkpoint folder, card, weights and task: it makes an env."""
    from panda_grasp_env.agents.policies.learned import Checkpoint, check_compatible

    checkpoint = Checkpoint(path)
    with learned_env(checkpoint, task) as env:
        try:
            check_compatible(checkpoint.load_policy(), checkpoint.config, env, checkpoint.name)
        except ValueError as error:
            return str(error)
    return None


def learned_env(checkpoint: Checkpoint, task: str, **options: Any) -> gym.Env:
    """The env a shipped checkpoint plays benchmark ``task`` in: on its own task the env it was trained on
    (``Checkpoint.make_env``); on another, that task's id with its scene and protocol options, seen and acted
    on as the checkpoint was trained (its ``AGENT_OPTIONS``); ``options`` on top of either."""
    if task == checkpoint.task:
        return checkpoint.make_env(**options)
    benchmark = BENCHMARKS[task]
    scene = {key: value for key, value in benchmark.options.items() if key not in AGENT_OPTIONS}
    agent = {key: value for key, value in checkpoint.config.env_kwargs.items() if key in AGENT_OPTIONS}
    return gym.make(f"panda_grasp_env:{benchmark.env_id}", **(scene | agent | options))


def phased_env(name: str, task: str, **options: Any) -> gym.Env:
    """The env phased agent ``name`` plays ``task`` in: the task's scene, seen and acted on as its first part
    was trained (``learned_env``), with the phased agent's own ``env_options`` on top (a wider heightmap)."""
    from panda_grasp_env.agents.policies.learned import Checkpoint
    from panda_grasp_env.agents.policies.phased import PHASED_AGENTS

    policies = PHASED_AGENTS[name]
    return learned_env(Checkpoint(policies.first), task, **(policies.env_options | options))


class FrozenMapping(tuple):
    """A mapping option value (an ``objects`` spec, ``randomization``, ``size_ranges``) as sorted (key, value)
    pairs: hashable, so that it can be part of an episode's spec."""


def frozen(value: Any) -> Any:
    """An option value made hashable: lists and tuples as tuples, mappings as ``FrozenMapping``, all the way
    down; ``ValueError`` for a value that cannot be."""
    if isinstance(value, FrozenMapping):
        return value
    if isinstance(value, (list, tuple)):
        return tuple(frozen(v) for v in value)
    if isinstance(value, Mapping):
        return FrozenMapping(sorted((str(k), frozen(v)) for k, v in value.items()))
    try:
        hash(value)
    except TypeError:
        raise ValueError(f"option values must be YAML scalars, lists or mappings, got {value!r}") from None
    return value


def thawed(value: Any) -> Any:
    """An option value as ``gymnasium.make`` and JSON take it: ``frozen`` undone (mappings as dicts, sequences
    as lists)."""
    if isinstance(value, FrozenMapping):
        return {k: thawed(v) for k, v in value}
    if isinstance(value, tuple):
        return [thawed(v) for v in value]
    return value


@dataclass(frozen=True)
class EpisodeSpec:
    """One benchmark episode: which agent plays which task on which seed, with which extra env options."""

    agent: str
    task: str
    seed: int
    #: ``gymnasium.make`` options on top of the task's (``evaluate.py --task-options``): (key, value) pairs
    #: sorted by key, values ``frozen`` (given as lists or mappings, they are frozen here).
    options: tuple[tuple[str, Any], ...] = ()

    def __post_init__(self) -> None:
        object.__setattr__(self, "options", tuple(sorted((str(k), frozen(v)) for k, v in self.options)))

    @property
    def make_options(self) -> dict[str, Any]:
        """The options as ``gymnasium.make`` takes them (``thawed``)."""
        return {key: thawed(value) for key, value in self.options}

    @property
    def key(self) -> str:
        """``agent/task/seed``, and the options as JSON if any (nested lists and mappings written out)."""
        key = f"{self.agent}/{self.task}/{self.seed}"
        return f"{key}/{json.dumps(self.make_options, sort_keys=True)}" if self.options else key

    def record(self) -> dict[str, Any]:
        """The spec as an episode record holds it: the options as [key, value] pairs, values as JSON."""
        options = [[key, thawed(value)] for key, value in self.options]
        return {"agent": self.agent, "task": self.task, "seed": self.seed, "options": options}


def task_options_from_pairs(pairs: list[str], tasks: list[str]) -> dict[str, Any]:
    """``KEY=VALUE`` strings (``--task-options``) as a mapping of YAML values (``apply_key_values``), checked
    by making each of the ``tasks``' envs with them; ``ValueError`` naming the bad pair or option."""
    options = apply_key_values({}, pairs, "--task-options")
    for key, value in options.items():
        try:
            frozen(value)  # a value an episode's spec can hold
        except ValueError as error:
            raise ValueError(f"--task-options {key}: {error}") from None
    for task in tasks if options else ():
        benchmark = BENCHMARKS[task]
        try:  # an option the protocol sets too (max_episode_steps on BuildAndBreak) is overridden
            gym.make(f"panda_grasp_env:{benchmark.env_id}", **(benchmark.options | options)).close()
        except (ValueError, TypeError) as error:
            raise ValueError(f"--task-options on {task} ({benchmark.env_id}): {error}") from None
    return options


@dataclass(frozen=True)
class RunProtocol:
    """One run's episodes: every (agent, task) pair that applies (``skip_reason``), on the chosen seeds, with
    ``task_options`` on top of each task's ``make`` options."""

    agents: tuple[str, ...]
    tasks: tuple[str, ...]
    #: The publication protocol's episode counts (``Benchmark.full_seeds``) instead of the quick one's.
    full: bool = False
    #: Episodes per (agent, task), seeds ``seed_start`` .. ``seed_start + seeds - 1``; None: the task's count.
    seeds: int | None = None
    seed_start: int = 0
    #: These seeds instead of ``seeds`` from ``seed_start``.
    seed_list: tuple[int, ...] | None = None
    #: ``gymnasium.make`` options for every task, on top of the task's own (``task_options_from_pairs``).
    task_options: Mapping[str, Any] = field(default_factory=dict)
    #: Modules that register tasks and agents from outside the package (``import_modules``).
    imports: tuple[str, ...] = ()

    def seeds_of(self, task: str) -> list[int]:
        """The seeds each (agent, ``task``) pair plays: ``seed_list``, else ``seeds`` (or the task's quick or full
        count) from ``seed_start``."""
        if self.seed_list is not None:
            return list(self.seed_list)
        count = self.seeds or BENCHMARKS[task].seeds(self.full)
        return list(range(self.seed_start, self.seed_start + count))

    def episode_specs(self) -> tuple[list[EpisodeSpec], dict[str, str]]:
        """The episodes to run, and the pairs left out: ``agent/task`` -> why that agent does not apply."""
        options = tuple(sorted(self.task_options.items()))
        specs, skipped = [], {}
        for task in self.tasks:
            for agent in self.agents:
                reason = skip_reason(agent, task)
                if reason is not None:
                    skipped[f"{agent}/{task}"] = reason
                    continue
                specs.extend(EpisodeSpec(agent, task, seed, options) for seed in self.seeds_of(task))
        return specs, skipped

    def checkpoints(self) -> list[Checkpoint]:
        """The shipped checkpoints among the agents (a phased agent's parts) that play at least one of the tasks."""
        from panda_grasp_env.agents.policies.learned import Checkpoint
        from panda_grasp_env.agents.policies.phased import PHASED_AGENTS

        names: list[str] = []
        for agent in self.agents:
            is_checkpoint = agent not in AGENTS and agent not in NAMED_AGENTS
            if is_checkpoint and any(skip_reason(agent, task) is None for task in self.tasks):
                names += PHASED_AGENTS[agent].phases.values() if agent in PHASED_AGENTS else [agent]
        return [Checkpoint(name) for name in dict.fromkeys(names)]

    def record(self, skipped: dict[str, str]) -> dict[str, Any]:
        """The protocol as ``results.json`` holds it, with the ``skipped`` pairs and their reasons."""
        return {
            "agents": list(self.agents),
            "tasks": list(self.tasks),
            "full": self.full,
            "env_ids": {t: BENCHMARKS[t].env_id for t in self.tasks},
            "seeds": {t: self.seeds_of(t) for t in self.tasks},
            "task_options": dict(self.task_options),
            "imports": imported_files(self.imports),
            "skipped": skipped,
        }
