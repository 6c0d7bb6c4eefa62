"""A fall-dynamics training run's config, checked (``FallConfig``: ``train.py`` with a ``kind: fall_dynamics``
config), and what ``--resume`` may change in it.

A pydantic dataclass, like a policy run's ``TrainConfig`` (``agents/learning/config.py``): each key's
``description`` says what values it takes, and ``checked_config`` quotes it in the ``ValueError`` of a bad
value; keys that must agree are checked together after each alone.
"""

from __future__ import annotations

from typing import Annotated, Any, Literal

from pydantic import ConfigDict, Field, StrictBool, StrictFloat, StrictInt, model_validator
from pydantic.dataclasses import dataclass

from panda_grasp_env.config_fields import Count, Seed
from panda_grasp_env.falls.shards import LABEL_SOURCES, read_metadata
from panda_grasp_env.tooling.runs import check_resume_changes, checked_config, config_value_error

#: The weight of a term of the training loss.
LossWeight = Annotated[StrictInt | StrictFloat, Field(ge=0, description="a number >= 0")]


@dataclass(frozen=True, config=ConfigDict(extra="forbid"))
class FallConfig:
    """A fall-dynamics training run.  ``dataset``: a folder written by ``python -m panda_grasp_env.falls``,
    checked after the keys alone (a clear error before the model is built)."""

    kind: Annotated[Literal["fall_dynamics"], Field(description="'fall_dynamics'")]
    name: str
    dataset: str
    label_source: Annotated[Literal[LABEL_SOURCES], Field(description=f"one of {list(LABEL_SOURCES)}")] = "labels"
    context: Count = 4  # true frames in
    rollout: Count = 5  # frames predicted and scored after them
    hidden: Count = 32  # ConvLSTM channels
    epochs: Count = 30
    batch_size: Count = 16
    learning_rate: Annotated[StrictInt | StrictFloat, Field(gt=0, lt=1, description="a number in (0, 1)")] = 0.002
    motion_loss_weight: LossWeight = 1.0
    next_frame_loss_weight: LossWeight = 0.0  # extra weight of the t+1 prediction's loss (the headline metric)
    # Also read the depth images (height maps; see model.py).
    use_depth: Annotated[StrictBool, Field(description="true or false")] = False
    height_loss_weight: LossWeight = 1.0
    # Rollouts shift the newest true frame's blocks by the summed displacements (FallPredictor's ``anchored``).
    anchored_rollout: Annotated[StrictBool, Field(description="true or false")] = False
    # The horizon (frames ahead) whose validation block IoU picks best.pt.
    select_horizon: Annotated[Literal[1, 5], Field(description="1 or 5")] = 1
    # An anchored model's displacements to every frame of the rollout, planned at once from the blocks' tracks
    # over the context frames (FallPredictor's ``track_horizon``, tracks.py).
    track_head: Annotated[StrictBool, Field(description="true or false")] = False
    # Epochs of fitting the track head alone on every training window's tracks before the ConvLSTM's epochs;
    # after them it is frozen and the ConvLSTM learns what it adds.  0: trained with the ConvLSTM.
    track_pretrain_epochs: Annotated[StrictInt, Field(ge=0, description="an int >= 0")] = 0
    # The sequences start at rest (structure falls): the track head is also fitted on windows whose context
    # is the first frame repeated, which is what the learned stability check asks about.
    track_windows_from_rest: Annotated[StrictBool, Field(description="true or false")] = False
    # Epochs of fitting a settle head (settling.py) on each training sequence's first frame against how far its
    # blocks went by the last, after the track head and before the ConvLSTM's epochs; then frozen.  The learned
    # stability check asks it instead of the track head.  0: no settle head.
    settle_epochs: Annotated[StrictInt, Field(ge=0, description="an int >= 0")] = 0
    # Sequences drawn per epoch (default: as many as the training split holds).
    epoch_sequences: Count | None = None
    # Validate each epoch on the first this many validation sequences (default: all).
    val_sequences: Count | None = None
    seed: Seed = 0
    # Stop (and checkpoint) after this many minutes of wall time in total.
    max_minutes: Annotated[StrictInt | StrictFloat | None, Field(gt=0, description="a positive number or null")] = None
    torch_threads: Count = 2

    @model_validator(mode="after")
    def _check_track_head(self) -> FallConfig:
        if self.track_head and not self.anchored_rollout:
            raise config_value_error("track_head", self.track_head, "false unless anchored_rollout is true")
        if self.track_pretrain_epochs and not self.track_head:
            raise config_value_error("track_pretrain_epochs", self.track_pretrain_epochs, "0 unless track_head is true")
        if self.track_windows_from_rest and not self.track_pretrain_epochs:
            raise config_value_error(
                "track_windows_from_rest", self.track_windows_from_rest, "false unless track_pretrain_epochs > 0"
            )
        return self

    @model_validator(mode="after")
    def _check_dataset(self) -> FallConfig:
        read_metadata(self.dataset)  # a clear error now, not after the model is built
        return self


#: What ``--resume`` may change in a fall-dynamics run; every other key built its model, data or optimiser.
FALL_RESUME_CHANGEABLE = ("epochs", "max_minutes", "torch_threads")


def check_fall_resume(saved: FallConfig, resumed: FallConfig) -> None:
    """``ValueError`` naming the keys a resumed run changed that it cannot (see ``FALL_RESUME_CHANGEABLE``)."""
    check_resume_changes(saved, resumed, FALL_RESUME_CHANGEABLE)


def fall_config(raw: dict[str, Any], source: str) -> FallConfig:
    """The checked ``FallConfig`` of a mapping read from ``source``; ``ValueError`` naming the bad key
    (``checked_config``)."""
    return checked_config(FallConfig, raw, source)
