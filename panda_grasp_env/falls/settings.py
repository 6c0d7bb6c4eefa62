"""How falling-tower sequences are recorded (``RecorderSettings``, ``python -m panda_grasp_env.falls``), checked.

A pydantic dataclass: each key's ``description`` says what values it takes, and ``checked_config`` quotes it
in the ``ValueError`` of a bad value; keys that must agree are checked together after each alone.  A training
run's config is ``panda_grasp_env.agents.learning.falls.config``.
"""

from __future__ import annotations

from typing import Annotated, Any, Literal

from pydantic import AfterValidator, ConfigDict, Field, StrictBool, StrictFloat, StrictInt, model_validator
from pydantic.dataclasses import dataclass

from panda_grasp_env.config_fields import Seed, distinct
from panda_grasp_env.model.scene import SceneConfig
from panda_grasp_env.primitives.parameters import PRIMITIVE_Z_RANGE
from panda_grasp_env.tasks.base import TOWER_BLOCKS
from panda_grasp_env.tooling.runs import config_value_error

#: The highest tower level (0: the base) a strike aims at: its centre (0.275 m) is the highest under the top
#: of ``PRIMITIVE_Z_RANGE`` (0.3 m), above which a primitive's height is clipped and it would hit another block.
HIGHEST_STRIKE_LEVEL = int((PRIMITIVE_Z_RANGE[1] - SceneConfig().block_size / 2) // SceneConfig().block_size)
#: Rendered image (width, height) the square crop is cut from: a block is ~10 px wide and a 64 px crop spans 0.33 m.
RENDER_SIZE = (224, 168)
#: How a tower is broken: an impulse on a block, a push by the hand, or either (mixed: half each).
BREAKERS = ("impulse", "push", "mixed")
#: What is recorded: a tower broken by a strike (``recorder.py``), or a piece set down on a partly built
#: structure, from rest (``structure_falls.py``; the tower settings do not apply).
SCENES = ("tower", "structures")
#: Settings added after the first recordings; their defaults record what the recorder did before them.
LATER_SETTINGS = ("tower_blocks", "strike_levels", "start_shift", "scene", "shifted_candidates")
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
    scene: Annotated[Literal[SCENES], Field(description=f"one of {list(SCENES)}")] = "tower"
    # Structures only: the candidate is drawn in thirds -- in the air, ready at its target, or ready and slid off
    # its target so that it may overhang its supports (``structure_falls.shifted_off``); off: half in the air,
    # half ready at the target (where nothing ready ever fell).
    shifted_candidates: StrictBool = False

    @model_validator(mode="after")
    def _check_shifts_are_of_structures(self) -> RecorderSettings:
        if self.shifted_candidates and self.scene != "structures":
            raise config_value_error("shifted_candidates", True, 'false unless scene is "structures"')
        return self

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
