"""The agents ``evaluate.py`` plays, registered by decorators the way tasks are (``registration.register_task``).

A planned baseline is a factory ``(env, seed, oracle) -> agent`` decorated with ``@register_baseline(task, ...)``:
``evaluate.py`` plays it as agent ``planned`` on those benchmark tasks, and with ``oracle=True`` as agent
``oracle`` (the same decisions on the simulator's true poses, where the agent has such a variant).  A scripted
low-level expert is a factory ``() -> agent`` decorated with ``@register_expert(task, ...)`` (agent ``expert``).
An agent acts through ``reset(observation, info)`` and ``act(observation, info) -> action``
(``panda_grasp_env.agents.policies.base``).

The built-in agents register in their own modules; an agent outside the package registers when its module is
imported (``evaluate.py --import MODULE``), so no shared table is edited.  A task that already has one raises
``ValueError`` naming it.
"""

from __future__ import annotations

from collections.abc import Callable
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
