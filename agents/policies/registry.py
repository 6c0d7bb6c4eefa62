"""The agents ``evaluate.py`` plays, registered by decorators the way tasks are (``registration.register_task``).

A planned baseline is a factory ``(env, seed, oracle) -> agent`` decorated with ``@register_baseline(task, ...)``:
``evaluate.py`` plays it as agent ``planned`` on those benchmark tasks, and with ``oracle=True`` as agent
``oracle`` (the same decisions on the simulator's true poses, where the agent has such a variant).  A scripted
low-level expert is a factory ``() -> agent`` decorated with ``@register_expert(task, ...)`` (agent ``expert``).
An agent acts through ``reset(observation, info)`` and ``act(observation, info) -> action``
(``panda_grasp_env.agents.policies.base``).

Any other agent -- one of your own, outside the package -- registers under its own name with
``@register_agent(name, task, ..., env_options=...)``: a factory ``(env, seed) -> agent`` that ``evaluate.py
--agents NAME`` plays on those tasks, in their benchmark envs with ``env_options`` on top (what it sees and how
it acts).

The built-in agents register in their own modules; an agent outside the package registers when its module is
imported (``evaluate.py --import MODULE``), so no shared table is edited.  A task that already has one raises
``ValueError`` naming it.
"""

from __future__ import annotations

from collections.abc import Callable, Mapping
from dataclasses import dataclass, field
from typing import Any, TypeVar

import gymnasium as gym

#: A planned baseline's factory: ``(env, seed, oracle) -> agent`` (seeded from the episode's seed).
BaselineFactory = Callable[[gym.Env, int, bool], Any]
#: Benchmark task -> its planned agent (``BASELINES[task](env, seed, oracle)``).
BASELINES: dict[str, BaselineFactory] = {}
#: Low-level benchmark task -> its scripted expert's factory (agent ``expert``: ``EXPERTS[task]()``).
EXPERTS: dict[str, Callable[[], Any]] = {}

Factory = TypeVar("Factory", bound=Callable[..., Any])


def _registrar(table: dict[str, Any], kind: str, tasks: tuple[str, ...]) -> Callable[[Factory], Factory]:
    if not tasks or not all(isinstance(t, str) and t for t in tasks):
        raise ValueError(f"register_{kind} needs one or more benchmark task names, got {tasks!r}")

    def register(factory: Factory) -> Factory:
        clashes = [t for t in tasks if t in table]
        if clashes:
            raise ValueError(f"{kind} {getattr(factory, '__name__', factory)!r}: task(s) {clashes} already have one")
        table.update(dict.fromkeys(tasks, factory))
        return factory

    return register


def register_baseline(*tasks: str) -> Callable[[Factory], Factory]:
    """Decorator: the factory ``(env, seed, oracle) -> agent`` is the planned (and oracle) agent of ``tasks``."""
    return _registrar(BASELINES, "baseline", tasks)


def register_expert(*tasks: str) -> Callable[[Factory], Factory]:
    """Decorator: the factory ``() -> agent`` (an agent class, say) is the scripted expert of ``tasks``."""
    return _registrar(EXPERTS, "expert", tasks)


#: The agents every ``evaluate.py`` run knows by these names: no registered agent may take one.
BUILT_IN_AGENTS = ("random", "planned", "oracle", "expert")


@dataclass(frozen=True)
class NamedAgent:
    """An agent registered under its own name (``register_agent``)."""

    #: ``(env, seed) -> agent``, seeded from the episode's seed.
    factory: Callable[[gym.Env, int], Any]
    #: The benchmark tasks it plays.
    tasks: tuple[str, ...]
    #: ``gymnasium.make`` options on top of each task's benchmark options: what it sees and how it acts
    #: (``obs_mode``, ``cameras``, ``action_mode``, ...).  The episode's own options (``--task-options``) win.
    env_options: Mapping[str, Any] = field(default_factory=dict)
    #: Whether it needs the ``learn`` extra (torch): without it ``evaluate.py`` skips it, naming the extra.
    needs_learning_stack: bool = False


#: Agent name -> the agent registered under it (``evaluate.py --agents NAME``).
NAMED_AGENTS: dict[str, NamedAgent] = {}


def register_agent(
    name: str, *tasks: str, env_options: Mapping[str, Any] | None = None, needs_learning_stack: bool = False
) -> Callable[[Factory], Factory]:
    """Decorator: the factory ``(env, seed) -> agent`` is ``evaluate.py``'s agent ``name`` on benchmark ``tasks``,
    playing in their envs with ``env_options`` on top (``needs_learning_stack``: it runs a torch model).  ``ValueError`` if the name is empty, built in
    (``BUILT_IN_AGENTS``), a shipped checkpoint's or taken, or if no task is named."""
    from panda_grasp_env.agents.policies.learned import available_checkpoints

    if not isinstance(name, str) or not name.isidentifier():
        raise ValueError(f"register_agent: the name must be an identifier (letters, digits, _), got {name!r}")
    if name in BUILT_IN_AGENTS or name in NAMED_AGENTS or name in available_checkpoints():
        raise ValueError(f"register_agent: the agent name {name!r} is built in, a shipped checkpoint's or taken")
    if not tasks or not all(isinstance(t, str) and t for t in tasks):
        raise ValueError(f"register_agent {name!r} needs one or more benchmark task names, got {tasks!r}")
    if env_options is not None and not isinstance(env_options, Mapping):
        raise ValueError(f"register_agent {name!r}: env_options must be a mapping, got {env_options!r}")

    def register(factory: Factory) -> Factory:
        if not callable(factory):
            raise ValueError(f"register_agent {name!r}: the factory must be callable, got {factory!r}")
        NAMED_AGENTS[name] = NamedAgent(factory, tuple(tasks), dict(env_options or {}), needs_learning_stack)
        return factory

    return register
