"""The config of a fall-dynamics training run (``train.py`` with a ``kind: fall_dynamics`` config), checked."""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any

from panda_grasp_env.falls.dataset import read_metadata
from panda_grasp_env.tooling.runs import config_from_mapping


@dataclass
class FallConfig:
    """A fall-dynamics training run.  ``dataset``: a folder written by ``python -m panda_grasp_env.falls``."""

    kind: str
    name: str
    dataset: str
    label_source: str = "labels"  # labels (simulator) | colour_labels (perception's colour segmentation)
    context: int = 4
    rollout: int = 5
    hidden: int = 32
    epochs: int = 30
    batch_size: int = 16
    learning_rate: float = 0.002
    motion_loss_weight: float = 1.0
    next_frame_loss_weight: float = 0.0  # extra weight of the t+1 prediction's loss (the headline metric)
    use_depth: bool = False  # also read the depth images (height maps; see panda_grasp_env/falls/model.py)
    height_loss_weight: float = 1.0
    seed: int = 0
    max_minutes: float | None = None
    torch_threads: int = 2

    def validate(self) -> None:
        for key in ("context", "rollout", "hidden", "epochs", "batch_size", "torch_threads"):
            value = getattr(self, key)
            if not isinstance(value, int) or isinstance(value, bool) or value < 1:
                raise ValueError(f"config {key}={value!r}: expected an int >= 1")
        if self.kind != "fall_dynamics":
            raise ValueError(f"config kind={self.kind!r}: expected 'fall_dynamics'")
        if self.label_source not in ("labels", "colour_labels"):
            raise ValueError(f"config label_source={self.label_source!r}: expected 'labels' or 'colour_labels'")
        if not (isinstance(self.learning_rate, (int, float)) and 0 < self.learning_rate < 1):
            raise ValueError(f"config learning_rate={self.learning_rate!r}: expected a number in (0, 1)")
        for key in ("motion_loss_weight", "next_frame_loss_weight", "height_loss_weight"):
            value = getattr(self, key)
            if not (isinstance(value, (int, float)) and not isinstance(value, bool) and value >= 0):
                raise ValueError(f"config {key}={value!r}: expected a number >= 0")
        if not isinstance(self.use_depth, bool):
            raise ValueError(f"config use_depth={self.use_depth!r}: expected true or false")
        if self.max_minutes is not None and not self.max_minutes > 0:
            raise ValueError(f"config max_minutes={self.max_minutes!r}: expected a positive number or null")
        read_metadata(self.dataset)  # a clear error now, not after the model is built


#: What ``--resume`` may change in a fall-dynamics run; every other key built its model, data or optimiser.
FALL_RESUME_CHANGEABLE = ("epochs", "max_minutes", "torch_threads")


def fall_config(raw: dict[str, Any], source: str) -> FallConfig:
    return config_from_mapping(FallConfig, raw, source)
    """The checked ``FallConfig`` of a mapping read from ``source``; ``ValueError`` naming the bad key."""
    return config_from_mapping(FallConfig, raw, source)
