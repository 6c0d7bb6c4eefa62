"""The one registry of the env: tasks by name and their Gymnasium ids.

A task module registers everything about itself with ``@register_task`` on its ``Task`` subclass: the
class (the env's ``task=``) and every id in its ``env_ids`` (with Gymnasium, at once).
``panda_grasp_env.tasks`` imports each module in its folder, so a new task file needs no other edit; a task
outside the package registers when its module is imported.  Which ids ``evaluate.py`` benchmarks, and on how
many seeds, evaluation declares (``panda_grasp_env.agents.evaluation.benchmarks``).

``gymnasium.make("panda_grasp_env:PandaTowerBuild-v0", obs_mode=..., action_mode=...)`` works in a
fresh interpreter: Gymnasium imports this package first.  Any env or task option can be passed to
``make``; ``max_episode_steps`` suits the id's default action mode and can be overridden the usual way.
"""

from __future__ import annotations

import inspect
from collections.abc import Mapping
from dataclasses import dataclass, field
from typing import Any, TypeVar

import gymnasium as gym

ENTRY_POINT = "panda_grasp_env.env:PandaEnv"


@dataclass(frozen=True)
class EnvId:
    """One Gymnasium id of a task (declared in the task's ``env_ids``, keyed by the id)."""

    #: Gymnasium's ``TimeLimit``: env steps (primitives or 40 ms control steps) before ``truncated``.
    max_episode_steps: int
    #: ``make`` defaults of the id, on top of ``task=<the task's name>``.
    options: Mapping[str, Any] = field(default_factory=dict)


#: Task name -> task class (``panda_grasp_env.tasks.base.Task`` subclasses).
TASKS: dict[str, type] = {}
#: Gymnasium id -> (default ``make`` keyword arguments, max_episode_steps).
ENV_IDS: dict[str, tuple[dict[str, Any], int]] = {}

TaskClass = TypeVar("TaskClass", bound=type)


def register_task(cls: TaskClass) -> TaskClass:
    """Class decorator: make a task available as ``task=cls.name`` and register its ``env_ids`` (with
    Gymnasium too).  Every name must be new: ``ValueError`` names a clash."""
    env_ids: Mapping[str, EnvId] = cls.env_ids
    clashes = [n for n in (cls.name,) if not n or n in TASKS]
    clashes += [i for i in env_ids if i in ENV_IDS]
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
