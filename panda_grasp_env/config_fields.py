"""Field types and checks the checked configs share: the env's options (``env_options.EnvOptions``), training
configs (``panda_grasp_env.agents.learning.config.TrainConfig``, ``panda_grasp_env.agents.learning.falls.config``)
and the falls recorder's settings (``panda_grasp_env.falls.settings``), all pydantic dataclasses."""

from __future__ import annotations

from collections.abc import Sequence
from typing import Annotated, Any, TypeVar

from pydantic import Field, StrictInt

#: A count (of steps, episodes, frames, threads, ...).
Count = Annotated[StrictInt, Field(ge=1, description="an int >= 1")]
#: A seed (the first of a run of seeds).
Seed = Annotated[StrictInt, Field(ge=0, description="an int >= 0")]
Items = TypeVar("Items", bound=Sequence[Any])


def distinct(values: Items) -> Items:
    """A config field's ``values`` if none repeats; else ``ValueError`` (a pydantic ``AfterValidator``)."""
    if len(set(values)) < len(values):
        raise ValueError(f"values that do not repeat, not {list(values)}")
    return values
