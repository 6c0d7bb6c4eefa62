"""Tasks: one module each, registered by name for the env's ``task=`` argument."""

from panda_grasp_env.tasks import build_and_break, grasp, push, tower_break, tower_build  # noqa: F401  (registration)
from panda_grasp_env.tasks.base import TASKS, Task, TaskStep, make_task, register_task

__all__ = ["TASKS", "Task", "TaskStep", "make_task", "register_task"]
