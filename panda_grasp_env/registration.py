"""The one registry: tasks by name, their Gymnasium ids and the benchmark tasks ``evaluate.py`` plays on them.

A task module registers everything about itself with ``@register_task`` on its ``Task`` subclass: the
class (the env's ``task=``), every id in its ``env_ids`` (with Gymnasium, at once) and every benchmark
entry of those ids.  ``panda_grasp_env.tasks`` imports each module in its folder, so a new task file
needs no other edit; a task outside the package registers when its module is imported.

``gymnasium.make("panda_grasp_env:PandaTowerBuild-v0", obs_mode=..., action_mode=...)`` works in a
fresh interpreter: Gymnasium imports this package first.  Any env or task option can be passed to
``make``; ``max_episode_steps`` suits the id's default action mode and can be overridden the usual way.
"""

from __future__ import annotations

import inspect
from collections.abc import Callable, Mapping
from dataclasses import dataclass, field
from typing import Any, TypeVar

import gymnasium as gym

ENTRY_POINT = "panda_grasp_env.env:PandaEnv"


@dataclass(frozen=True)
class Benchmark:
    """An ``evaluate.py`` task played on an id: extra ``make`` options, and the episodes (seeds) of its quick
    and full protocols."""

    options: Mapping[str, Any] = field(default_factory=dict)
    quick_seeds: int = 10
    full_seeds: int = 100
    #: ``env.reset(options=...)`` of each episode, from its seed (None: none): what one episode plays when the
    #: protocol sweeps a list (each test object in turn), not a random draw.
    reset_options: Callable[[int], dict[str, Any]] | None = None
    #: Whether ``evaluate.py`` without ``--tasks`` plays it (False: only when named, e.g. the mesh benchmarks,
    #: which need the objects extra and minutes an episode, and the 6- and 8-block towers).
    by_default: bool = True


@dataclass(frozen=True)
class EnvId:
    """One Gymnasium id of a task (declared in the task's ``env_ids``, keyed by the id)."""

    #: Gymnasium's ``TimeLimit``: env steps (primitives or 40 ms control steps) before ``truncated``.
    max_episode_steps: int
    #: ``make`` defaults of the id, on top of ``task=<the task's name>``.
    options: Mapping[str, Any] = field(default_factory=dict)
    #: Benchmark tasks of ``evaluate.py`` played on this id: name -> ``Benchmark`` (or its ``make`` options alone).
    benchmarks: Mapping[str, Benchmark | Mapping[str, Any]] = field(default_factory=dict)


#: Task name -> task class (``panda_grasp_env.tasks.base.Task`` subclasses).
TASKS: dict[str, type] = {}
#: Gymnasium id -> (default ``make`` keyword arguments, max_episode_steps).
ENV_IDS: dict[str, tuple[dict[str, Any], int]] = {}
#: Benchmark task of ``evaluate.py`` -> (Gymnasium id, extra ``make`` options).
BENCHMARKS: dict[str, tuple[str, dict[str, Any]]] = {}
#: Benchmark task -> episodes of the quick and of the full protocol.
BENCHMARK_SEEDS: dict[str, tuple[int, int]] = {}
#: The benchmark tasks ``evaluate.py`` plays when ``--tasks`` is not given.
DEFAULT_BENCHMARKS: list[str] = []
#: Benchmark task -> its episodes' ``reset`` options from the seed (``Benchmark.reset_options``), where it has them.
BENCHMARK_RESET_OPTIONS: dict[str, Callable[[int], dict[str, Any]]] = {}

TaskClass = TypeVar("TaskClass", bound=type)


def register_task(cls: TaskClass) -> TaskClass:
    """Class decorator: make a task available as ``task=cls.name`` and register its ``env_ids`` (with
    Gymnasium too) and their benchmarks.  Every name must be new: ``ValueError`` names a clash."""
    env_ids: Mapping[str, EnvId] = cls.env_ids
    clashes = [n for n in (cls.name,) if not n or n in TASKS]
    clashes += [i for i in env_ids if i in ENV_IDS]
    clashes += [b for spec in env_ids.values() for b in spec.benchmarks if b in BENCHMARKS]
    clashes += [
        i for i in env_ids if i in gym.registry and gym.registry[i].entry_point != ENTRY_POINT
    ]  # another package's
    if clashes:
        raise ValueError(f"task {cls.__name__}: name(s) {clashes} are empty or already registered")
    TASKS[cls.name] = cls
    for env_id, spec in env_ids.items():
        kwargs = {"task": cls.name, **spec.options}
        ENV_IDS[env_id] = (kwargs, spec.max_episode_steps)
        if env_id not in gym.registry:
            gym.register(id=env_id, entry_point=ENTRY_POINT, kwargs=kwargs, max_episode_steps=spec.max_episode_steps)
        for name, benchmark in spec.benchmarks.items():
            if not isinstance(benchmark, Benchmark):
                benchmark = Benchmark(options=benchmark)
            BENCHMARKS[name] = (env_id, dict(benchmark.options))
            BENCHMARK_SEEDS[name] = (benchmark.quick_seeds, benchmark.full_seeds)
            if benchmark.by_default:
                DEFAULT_BENCHMARKS.append(name)
            if benchmark.reset_options is not None:
                BENCHMARK_RESET_OPTIONS[name] = benchmark.reset_options
    return cls


def make_task(name: str, options: dict[str, Any]) -> Any:
    """Instantiate task ``name``; unknown names or options raise ``ValueError`` listing the valid ones."""
    if not isinstance(name, str) or name not in TASKS:
        raise ValueError(f"unknown task {name!r}; valid: {sorted(TASKS)}")
    cls = TASKS[name]
    valid = task_options(cls)
    unknown = sorted(set(options) - set(valid))
    if unknown:
        raise ValueError(f"unknown option(s) {unknown} for task {name!r}; valid: {valid}")
    return cls(**options)


def task_options(cls: type) -> list[str]:
    """The options a task class takes: its ``__init__``'s named parameters, and, where that passes
    ``**kwargs`` on, those of the base classes it passes them to."""
    names: list[str] = []
    for klass in cls.__mro__:
        if "__init__" not in vars(klass):
            continue
        parameters = inspect.signature(klass.__init__).parameters.values()
        named = (inspect.Parameter.POSITIONAL_OR_KEYWORD, inspect.Parameter.KEYWORD_ONLY)
        names += [p.name for p in parameters if p.kind in named and p.name != "self" and p.name not in names]
        if not any(p.kind == inspect.Parameter.VAR_KEYWORD for p in parameters):
            break
    return names
