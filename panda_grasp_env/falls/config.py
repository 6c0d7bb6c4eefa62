"""The falls' configs, checked: how sequences are recorded (``RecorderSettings``, ``python -m
panda_grasp_env.falls``) and a fall-dynamics training run (``FallConfig``, ``train.py`` with a
``kind: fall_dynamics`` config).

Both are pydantic dataclasses: each key's ``description`` says what values it takes, and ``checked_config``
quotes it in the ``ValueError`` of a bad value; keys that must agree are checked together after each alone.
"""

from __future__ import annotations

from typing import Annotated, Any, Literal

from pydantic import AfterValidator, ConfigDict, Field, StrictBool, StrictFloat, StrictInt, model_validator
from pydantic.dataclasses import dataclass

from panda_grasp_env.config_fields import Count, Seed, distinct
from panda_grasp_env.falls.dataset import LABEL_SOURCES, read_metadata
from panda_grasp_env.model.scene import SceneConfig
from panda_grasp_env.primitives.parameters import PRIMITIVE_Z_RANGE
from panda_grasp_env.tasks.base import TOWER_BLOCKS
from panda_grasp_env.tooling.runs import checked_config, config_value_error

# --- recording -----------------------------------------------------------------------------------

#: The highest tower level (0: the base) a strike aims at: its centre (0.275 m) is the highest under the top
#: of ``PRIMITIVE_Z_RANGE`` (0.3 m), above which a primitive's height is clipped and it would hit another block.
HIGHEST_STRIKE_LEVEL = int((PRIMITIVE_Z_RANGE[1] - SceneConfig().block_size / 2) // SceneConfig().block_size)
#: Rendered image (width, height) the square crop is cut from: a block is ~10 px wide and a 64 px crop spans 0.33 m.
RENDER_SIZE = (224, 168)
#: How a tower is broken: an impulse on a block, a push by the hand, or either (mixed: half each).
BREAKERS = ("impulse", "push", "mixed")
#: Settings added after the first recordings; their defaults record what the recorder did before them.
LATER_SETTINGS = ("tower_blocks", "strike_levels", "start_shift")
#: The widest square crop (pixels): the rendered image's height.
LARGEST_CROP = min(RENDER_SIZE)
#: An impulse's magnitude (N s).
ImpulseMagnitude = Annotated[StrictInt | StrictFloat, Field(gt=0, le=1.0)]
#: A tower's height (blocks).
TowerHeight = Annotated[StrictInt, Field(ge=TOWER_BLOCKS[0], le=TOWER_BLOCKS[1])]
#: A tower level a strike may aim at (0: the base).
StrikeLevel = Annotated[StrictInt, Field(ge=0, le=HIGHEST_STRIKE_LEVEL)]


def control_step_multiple(seconds: float) -> float:
    """``seconds`` if it is a whole number of 0.04 s control steps; else ``ValueError``."""
    if abs(seconds / 0.04 - round(seconds / 0.04)) >= 1e-6:
        raise ValueError(f"{seconds} s is no whole number of 0.04 s control steps")
    return seconds


def ordered_pair(pair: tuple[Any, Any]) -> tuple[Any, Any]:
    """``(low, high)`` if low <= high; else ``ValueError``."""
    if pair[0] > pair[1]:
        raise ValueError(f"{pair[0]} is above {pair[1]}")
    return pair


@dataclass(frozen=True, config=ConfigDict(extra="forbid"))
class RecorderSettings:
    """How sequences are recorded (``panda_grasp_env/falls/recorder.py``).  Times in seconds, impulses in N s,
    distances in metres.  Checked whenever made; ``checked_config`` makes one from a mapping, with errors
    worded as for any config."""

    frames: Annotated[StrictInt, Field(ge=2, le=100, description="an int in [2, 100]")] = 15
    # One 25 Hz control step: 25 frames per second.
    frame_interval: Annotated[
        StrictInt | StrictFloat,
        Field(ge=0.04, le=1.0, description="a multiple of the 0.04 s control step, up to 1 s"),
        AfterValidator(control_step_multiple),
    ] = 0.04
    # Pixels, square, centred on the tower's base.
    crop: Annotated[StrictInt, Field(ge=16, le=LARGEST_CROP, description=f"an int in [16, {LARGEST_CROP}]")] = 64
    breaker: Annotated[Literal[BREAKERS], Field(description=f"one of {list(BREAKERS)}")] = "impulse"
    impulse: Annotated[
        tuple[ImpulseMagnitude, ImpulseMagnitude],
        Field(description="(low, high) with 0 < low <= high <= 1 N s"),
        AfterValidator(ordered_pair),
    ] = (0.08, 0.2)
    shard_size: Annotated[StrictInt, Field(ge=1, description="an int >= 1")] = 50
    seed: Seed = 0  # sequence i uses env seed seed + i
    # Tower heights (blocks), one drawn per sequence (``tower_height``).
    tower_blocks: Annotated[
        tuple[TowerHeight, ...],
        Field(
            min_length=1,
            description=f"a non-empty tuple of distinct ints in [{TOWER_BLOCKS[0]}, {TOWER_BLOCKS[1]}]",
        ),
        AfterValidator(distinct),
    ] = (4,)
    # Levels (0: the base) the struck block is drawn from, uniformly, up to the tower's top and
    # HIGHEST_STRIKE_LEVEL: a tall tower struck low mostly stands (an impulse in the lower half of a 6-block
    # tower toppled 3 of 19, in the upper half 19 of 26; see docs/falling-tower.md).
    strike_levels: Annotated[
        tuple[StrikeLevel, StrikeLevel],
        Field(description=f"(lowest, highest) ints with 0 <= lowest <= highest <= {HIGHEST_STRIKE_LEVEL}"),
        AfterValidator(ordered_pair),
    ] = (0, HIGHEST_STRIKE_LEVEL)
    # Metres: 0 starts the frames at the first block moving faster than the recorder's MOTION_SPEED; more also
    # waits until a block is that far from where it stood (a tall tower touched by the pushing fingers jitters
    # at up to 0.16 m/s for seconds before it moves; see docs/falling-tower.md).
    start_shift: Annotated[StrictInt | StrictFloat, Field(ge=0, le=0.05, description="in [0, 0.05] m")] = 0.0

    @model_validator(mode="after")
    def _check_strikes_hit_every_tower(self) -> RecorderSettings:
        lowest_tower = min(self.tower_blocks)
        if self.strike_levels[0] >= lowest_tower:
            raise config_value_error(
                "strike_levels",
                self.strike_levels,
                f"a lowest level struck under the top of the lowest tower ({lowest_tower} blocks: levels "
                f"0-{lowest_tower - 1})",
            )
        return self


# --- training ------------------------------------------------------------------------------------

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
    # Also read the depth images (height maps; see panda_grasp_env/falls/model.py).
    use_depth: Annotated[StrictBool, Field(description="true or false")] = False
    height_loss_weight: LossWeight = 1.0
    # Rollouts shift the newest true frame's blocks by the summed displacements (FallPredictor's ``anchored``).
    anchored_rollout: Annotated[StrictBool, Field(description="true or false")] = False
    # The horizon (frames ahead) whose validation block IoU picks best.pt.
    select_horizon: Annotated[Literal[1, 5], Field(description="1 or 5")] = 1
    # An anchored model's displacements to every frame of the rollout, planned at once from the blocks' tracks
    # over the context frames (FallPredictor's ``track_horizon``, panda_grasp_env/falls/tracks.py).
    track_head: Annotated[StrictBool, Field(description="true or false")] = False
    # Epochs of fitting the track head alone on every training window's tracks before the ConvLSTM's epochs;
    # after them it is frozen and the ConvLSTM learns what it adds.  0: trained with the ConvLSTM.
    track_pretrain_epochs: Annotated[StrictInt, Field(ge=0, description="an int >= 0")] = 0
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
        return self

    @model_validator(mode="after")
    def _check_dataset(self) -> FallConfig:
        read_metadata(self.dataset)  # a clear error now, not after the model is built
        return self


#: What ``--resume`` may change in a fall-dynamics run; every other key built its model, data or optimiser.
FALL_RESUME_CHANGEABLE = ("epochs", "max_minutes", "torch_threads")


def fall_config(raw: dict[str, Any], source: str) -> FallConfig:
    """The checked ``FallConfig`` of a mapping read from ``source``; ``ValueError`` naming the bad key
    (``checked_config``)."""
    return checked_config(FallConfig, raw, source)
