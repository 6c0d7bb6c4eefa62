"""Tasks: one module each.  Importing this package imports every module in its folder, whose
``@register_task`` classes then register themselves (``panda_grasp_env.registration``)."""

import importlib
import pkgutil

from panda_grasp_env.tasks.base import REWARD_TYPES, Task, TaskStep, dense_reward

for _module in pkgutil.iter_modules(__path__):
    importlib.import_module(f"{__name__}.{_module.name}")

__all__ = ["REWARD_TYPES", "Task", "TaskStep", "dense_reward"]
