"""What the ``learn`` extra installs, and one error naming it where it is missing.

``pip install panda_grasp_env`` gives every env id, perception and the scripted agents; the learning stack
(torch, Stable-Baselines3, sb3-contrib, tensorboard, safetensors) is the ``learn`` extra, which the README's
main command installs.  Code that needs it calls ``require_learning_stack`` first, so a lean install fails
with one line saying what to install, never deep inside an import.
"""

from __future__ import annotations

from importlib.util import find_spec

#: The import names the ``learn`` extra provides.
LEARNING_PACKAGES = ("torch", "stable_baselines3", "sb3_contrib", "safetensors")
#: How to install it (torch's CPU build first: a bare torch requirement pulls several GB of CUDA packages).
LEARN_INSTALL = "pip install torch==2.13.0 && pip install 'panda_grasp_env[learn]'"


def missing_learning_packages() -> list[str]:
    """The ``LEARNING_PACKAGES`` this environment lacks (none when the ``learn`` extra is installed)."""
    return [name for name in LEARNING_PACKAGES if find_spec(name) is None]


def learning_stack_problem(what: str) -> str | None:
    """Why ``what`` (a learned agent, a training run) cannot run here, naming the extra; None if it can."""
    missing = missing_learning_packages()
    if not missing:
        return None
    return f"{what} needs the learn extra ({', '.join(missing)} not installed): {LEARN_INSTALL}"


def require_learning_stack(what: str) -> None:
    """``ModuleNotFoundError`` naming the ``learn`` extra unless its packages are installed."""
    problem = learning_stack_problem(what)
    if problem is not None:
        raise ModuleNotFoundError(problem)
