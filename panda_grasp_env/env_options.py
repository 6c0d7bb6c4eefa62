"""``EnvOptions``: ``PandaEnv``'s env options, declared once and checked before anything is built.

A frozen pydantic dataclass: each field is one env option, with its type, its default and a docstring that
says what it does; its ``description`` says what values it takes, and ``EnvOptions.checked`` turns the first
bad one into a ``ValueError`` that names it, its value and what it takes.  ``PandaEnv.__init__`` takes them as
keywords (``**options``: the env options are ``ENV_OPTIONS``, the rest go to the task), and its signature
(``with_env_options``) is read from the fields.
"""

from __future__ import annotations

import functools
import inspect
import os
from collections.abc import Callable
from dataclasses import fields, replace
from typing import Annotated, Any, Literal, get_type_hints

import mujoco
import numpy as np
from pydantic import (
    AfterValidator,
    BeforeValidator,
    ConfigDict,
    Field,
    InstanceOf,
    PlainValidator,
    Strict,
    ValidationError,
    ValidationInfo,
    field_validator,
    model_validator,
)
from pydantic.dataclasses import dataclass

from panda_grasp_env.actions import ACTION_MODES, ActionContext, ActionMode
from panda_grasp_env.config_fields import distinct
from panda_grasp_env.model.scene import CAMERA_NAMES, PRIMITIVE_NOSLIP_ITERATIONS, SceneConfig
from panda_grasp_env.observations import parse_obs_mode
from panda_grasp_env.perception.heightmap import DEFAULT_BOUNDS, HeightmapGrid
from panda_grasp_env.primitives.parameters import PrimitiveSettings
from panda_grasp_env.randomization import Randomization
from panda_grasp_env.sim.rendering import RENDER_MODES, advertised_render_modes, display_available
from panda_grasp_env.sim.workcell import Workcell
from panda_grasp_env.tasks import REWARD_TYPES, Task

#: Largest image or render side, pixels.
MAX_IMAGE_SIDE = 2048
#: Most headings of the ``pixel`` action mode (VPG uses 16).
MAX_ROTATIONS = 64
#: A heightmap grid has this many cells per side, at least and at most.
GRID_SIDES = (16, 1024)
#: Start state -> the option that sets the probability of an episode starting there.
START_OPTIONS = {
    "in_hand": "start_in_hand",
    "above_object": "start_above_object",
    "behind_object": "start_behind_object",
}

#: The env options that set how an agent sees and acts (observation, action mode and their
#: resolutions); the others, and the task options, set the scene and the protocol.
AGENT_OPTIONS = frozenset(
    {
        "obs_mode",
        "action_mode",
        "cameras",
        "image_size",
        "heightmap_resolution",
        "heightmap_bounds",
        "rotations",
        "primitive_z",
        "push_distance",
        "block_gripper",
        "planner",
    }
)


def python_scalar(value: Any) -> Any:
    """A numpy scalar as the Python value it holds (``np.int64(3)`` -> 3, ``np.bool_(True)`` -> True), so that
    the strict types below take it as they take the Python value; anything else as it is."""
    return value.item() if isinstance(value, np.generic) else value


def one_of(valid: tuple[str, ...]) -> PlainValidator:
    """The check of an option that names one of ``valid``: ``ValueError`` ``unknown <option> <value>; valid: [...]``."""

    def check(value: Any, info: ValidationInfo) -> str:
        if not (isinstance(value, str) and value in valid):
            raise ValueError(f"unknown {info.field_name} {value!r}; valid: {list(valid)}")
        return value

    return PlainValidator(check)


def render_mode_here(render_mode: Any) -> str | None:
    """``render_mode`` if it is None or a render mode that works on this machine; else ``ValueError``."""
    if render_mode == "human" and not display_available():
        raise ValueError(
            "render_mode='human' needs a display whose server answers (DISPLAY or WAYLAND_DISPLAY names none that "
            f"does: DISPLAY={os.environ.get('DISPLAY')!r}); "
            "use 'rgb_array' and save the frames, e.g. with gymnasium's RecordVideo"
        )
    if render_mode is not None and not (isinstance(render_mode, str) and render_mode in RENDER_MODES):
        raise ValueError(f"unknown render_mode {render_mode!r}; valid: {advertised_render_modes()} or None")
    return render_mode


def valid_obs_mode(obs_mode: Any) -> str:
    """``obs_mode`` if ``parse_obs_mode`` takes it (it raises the ``ValueError`` naming the bad part)."""
    parse_obs_mode(obs_mode)
    return obs_mode


def grid_bounds(bounds: Any) -> Any:
    """``bounds`` if a heightmap grid can span them (``HeightmapGrid`` checks each low < high)."""
    return HeightmapGrid(bounds).bounds


#: An int (a numpy int too), not a bool.
Whole = Annotated[int, BeforeValidator(python_scalar), Strict()]
#: A finite real number (a numpy one too), not a bool.
Real = Annotated[float, BeforeValidator(python_scalar), Strict(), Field(allow_inf_nan=False)]
#: A bool (a numpy bool too).
Flag = Annotated[bool, BeforeValidator(python_scalar), Strict(), Field(description="a bool")]
#: An image side, pixels.
Side = Annotated[Whole, Field(ge=1, le=MAX_IMAGE_SIDE)]
#: (width, height) pixels.
ImageSize = Annotated[tuple[Side, Side], Field(description=f"(width, height) in ints from 1 to {MAX_IMAGE_SIDE}")]
#: A start state's probability.
Probability = Annotated[Real, Field(ge=0.0, le=1.0, description="a probability in [0, 1]")]
#: (low, high) world metres.
Span = tuple[Real, Real]


@dataclass(frozen=True, config=ConfigDict(validate_default=True))  # a default of None becomes the task's
class EnvOptions:
    """``PandaEnv``'s env options (``gym.make`` keyword arguments besides the task's options), declared once:
    each field's type, default and docstring here are the option's; ``PandaEnv``'s signature and its list of
    valid names are read from them.  Checked for one task, the working forms (grid, modalities, start
    curriculum) are read from them: build it with ``EnvOptions.checked``, which knows the task."""

    # Where an option's own check is its whole validation (a PlainValidator), the type is what a user passes
    # (the signature's) and pydantic neither converts the value nor answers before the check does.
    obs_mode: Annotated[str, PlainValidator(valid_obs_mode)] = "state"
    """``state``, ``proprio``, ``rgb``, ``depth``, ``segmentation``, ``heightmap`` or a ``+`` combination."""
    action_mode: Annotated[str | None, one_of(tuple(ACTION_MODES))] = None
    """``primitive``, ``pixel``, ``pixel_factored``, ``ee_delta``, ``joint`` or ``grasp_pose`` (default: the
    task's).  Once checked, the action mode's name: the one given, or the task's default."""
    render_mode: Annotated[str | None, PlainValidator(render_mode_here)] = None
    """``rgb_array`` / ``depth_array`` (front camera), ``rgb_array_list`` (the frames since the last
    ``reset``/``render``, taken at ``metadata["render_fps"]`` of simulated time, inside primitives too:
    ``video.RecordMotionVideo``) or ``human`` (MuJoCo viewer)."""
    cameras: Annotated[
        tuple[Literal[CAMERA_NAMES], ...],
        BeforeValidator(lambda cameras: (cameras,) if isinstance(cameras, str) else cameras),  # one name
        AfterValidator(distinct),
        Field(min_length=1, description=f"distinct names from {list(CAMERA_NAMES)}"),
    ] = ("overhead",)
    """Cameras for image observations (``overhead``, ``front``, ``wrist``): a tuple of them, or one name."""
    image_size: ImageSize = (84, 84)
    """(width, height) of image observations, pixels."""
    heightmap_resolution: Annotated[Real, Field(gt=0.0, description="a positive number of metres")] = 0.002
    """Metres per heightmap cell (``heightmap`` obs and ``pixel`` actions)."""
    heightmap_bounds: Annotated[
        tuple[Span, Span, Span],
        AfterValidator(grid_bounds),
        Field(description="((x0, x1), (y0, y1), (z0, z1)) metres, each low < high"),
    ] = DEFAULT_BOUNDS
    """((x0, x1), (y0, y1), (z0, z1)) world metres the heightmap covers."""
    rotations: Annotated[Whole, Field(ge=1, le=MAX_ROTATIONS, description=f"an int from 1 to {MAX_ROTATIONS}")] = 16
    """Number of headings in the ``pixel`` action mode (VPG: 16)."""
    primitive_z: Flag = False
    """Add a z component to ``primitive`` actions (default: heights chosen from the scene)."""
    push_distance: Annotated[Real, Field(gt=0.0, le=0.3, description="in (0, 0.3] m")] = 0.1
    """Push length, metres."""
    block_gripper: Flag = False
    """``ee_delta`` only: fingers held closed, the action is (dx, dy, dz) (panda-gym's Push)."""
    render_size: ImageSize = (640, 480)
    """(width, height) of ``render()`` frames."""
    planner: Annotated[str, Strict(), Field(description="an OMPL planner's name (a str)")] = "RRTConnect"
    """OMPL planner of the ``grasp_pose`` mode (``panda_grasp_env.control.planning.PLANNERS``)."""
    scene: Annotated[
        InstanceOf[SceneConfig] | None, Field(description="a panda_grasp_env.model.scene.SceneConfig or None")
    ] = None
    """Base ``SceneConfig`` (block size, masses, friction, gripper force, ...); the task sets the objects."""
    start_in_hand: Probability = 0.0
    """Low-level modes (``ee_delta``, ``joint``) only, with a task that can start so (``Grasp``, ``TowerBuild``):
    the probability (0-1) that an episode starts with the task's object already between the closed fingers
    where it lay (``Task.start_object``: the object to lift, the next block to stack) -- a training curriculum,
    as resets to demonstration states (Nair et al. 2018); evaluation keeps 0.  An object too wide for the open
    fingers at the fixed heading starts the episode normally.

    The start probabilities sum to at most 1; with any of them ``info["start"]`` says how an episode started:
    ``ready`` or one of ``Task.start_states`` (``in_hand``, ``above_object``, ``behind_object``: those the task
    supports, relative to ``Task.start_object``)."""
    start_above_object: Probability = 0.0
    """As ``start_in_hand``: the probability that an episode starts with the open hand straight above that
    object, anywhere from around it to the usual start height (uniform); the two curricula together cover the
    way from the usual start to the object."""
    start_behind_object: Probability = 0.0
    """As ``start_in_hand``, for Push: the probability that an episode starts with the fingers closed and the
    hand at the block's height behind it on the line from the goal through the block, 0-10 cm (uniform) short
    of touching it -- where a push towards the goal begins."""
    randomization: Annotated[Randomization | dict[str, Any] | bool | None, PlainValidator(Randomization.of)] = None
    """Domain randomisation at each reset (``randomization.Randomization``, a dict of its fields, or True for
    its defaults): lights, fixed camera poses, object hues, table colour, object mass and friction,
    depth-observation noise.  None (default): off, and nothing is drawn."""
    reward_type: Annotated[str, one_of(REWARD_TYPES)] = "sparse"
    """The low-level reward of a goal-conditioned task (``ee_delta``/``joint`` modes of Push, Lift, Stack):
    ``sparse`` (default; Fetch's 0 when every goal point is within 5 cm, else -1) or ``dense`` (panda-gym's:
    minus the distance, metres, between achieved and desired goal).  ``compute_reward`` gives the same, so HER
    relabels either.  A diverged step earns -1 in both."""

    @field_validator("action_mode", mode="before")
    @classmethod
    def _task_default(cls, action_mode: Any, info: ValidationInfo) -> Any:
        return info.context["task"].default_action_mode if action_mode is None else action_mode

    @model_validator(mode="after")
    def _fit_together_and_the_task(self, info: ValidationInfo) -> EnvOptions:
        task: Task = info.context["task"]
        low, high = GRID_SIDES
        if not all(low <= side <= high for side in self.grid.shape):
            raise ValueError(
                f"heightmap_resolution={self.heightmap_resolution!r} over heightmap_bounds={self.heightmap_bounds!r} "
                f"gives a {self.grid.shape} grid; each side must have {low}-{high} cells"
            )
        if self.block_gripper and self.action_mode != "ee_delta":
            raise ValueError(f"block_gripper=True needs action_mode='ee_delta', not {self.action_mode!r}")
        for state, name in START_OPTIONS.items():
            if getattr(self, name) and not (self.mode.low_level and state in task.start_states):
                raise ValueError(
                    f"{name} needs a low-level action mode (ee_delta, joint) and a task that can start "
                    f"{state.replace('_', ' ')}; got action_mode={self.action_mode!r}, task={task.name!r} "
                    f"(its start states: {list(task.start_states)})"
                )
        if sum(self.start_curriculum.values()) > 1.0:
            raise ValueError(f"the start_* probabilities must sum to <= 1, got {sum(self.start_curriculum.values())}")
        goals = task.goal_conditioned and (self.mode.low_level or task.goals_in_every_mode)
        if self.reward_type == "dense" and not goals:
            raise ValueError(
                f"reward_type='dense' is the goal distance of a goal-conditioned task (in a low-level action "
                f"mode, unless the task has goals in every mode); {task.name!r} in {self.action_mode!r} mode has "
                f"no goal reward to make dense"
            )
        return self

    @classmethod
    def checked(cls, task: Task, **options: Any) -> EnvOptions:
        """The env options given (by name; the others take their defaults), checked for ``task``; ``ValueError``
        naming the first bad one, its value and what it takes (the field's ``description``, else what its check
        said)."""
        try:
            return cls.__pydantic_validator__.validate_python(options, context={"task": task})  # type: ignore[attr-defined]
        except ValidationError as error:
            problem = error.errors(include_url=False)[0]
        said = str(problem.get("ctx", {}).get("error", problem["msg"]))
        if not problem["loc"]:  # a check across options, or against the task
            raise ValueError(said) from None
        name = problem["loc"][0]
        expected = cls.__pydantic_fields__[name].description  # type: ignore[attr-defined]
        if expected is None:  # its check's message names it
            raise ValueError(said) from None
        value = options[name]
        shown = type(value).__name__ if problem["type"] == "is_instance_of" else repr(value)
        raise ValueError(f"{name} must be {expected}, got {shown}") from None

    @property
    def mode(self) -> type[ActionMode]:
        """The action mode's class."""
        return ACTION_MODES[self.action_mode]

    @property
    def modalities(self) -> tuple[str, ...]:
        """The parts of ``obs_mode``."""
        return parse_obs_mode(self.obs_mode)

    @functools.cached_property
    def grid(self) -> HeightmapGrid:
        """``heightmap_bounds`` at ``heightmap_resolution``."""
        return HeightmapGrid(self.heightmap_bounds, self.heightmap_resolution)

    @property
    def start_curriculum(self) -> dict[str, float]:
        """Start state -> probability of an episode starting there (a training curriculum; empty: none)."""
        return {state: getattr(self, name) for state, name in START_OPTIONS.items() if getattr(self, name)}

    def scene_config(self, task: Task) -> SceneConfig:
        """The workcell's scene: ``scene`` (or the defaults) as ``task`` sets it, with the task's fixtures after
        those of ``scene`` (if any)."""
        # Low-level modes: no noslip pass unless the scene sets one.  It stops a held block creeping in the
        # fingers during long primitive carries (place accuracy); at 25 Hz control it costs ~10 % of the rate.
        base = self.scene or SceneConfig()
        if base.noslip_iterations is None:
            base = replace(base, noslip_iterations=0 if self.mode.low_level else PRIMITIVE_NOSLIP_ITERATIONS)
        config = task.scene_config(base)
        given = config.fixtures
        if given is None:
            return replace(config, fixtures=task.add_fixtures)

        def both(spec: mujoco.MjSpec) -> None:
            given(spec)
            task.add_fixtures(spec)

        return replace(config, fixtures=both)

    def action_context(self, task: Task, cell: Workcell, heightmap: Callable[[], np.ndarray]) -> ActionContext:
        """What the action mode is built from: ``cell``, the primitives ``task`` offers with these options'
        parameters, the heightmap grid and headings, and ``heightmap`` (the current one, metres above the
        table)."""
        impulse = getattr(task, "impulse_magnitude", PrimitiveSettings.impulse_magnitude)
        settings = PrimitiveSettings(task.primitives, self.primitive_z, self.push_distance, impulse)
        return ActionContext(cell, settings, self.grid, self.rotations, heightmap, self.block_gripper, self.planner)


#: The env options' names, in order (``PandaEnv``'s keyword arguments that are not the task's options).
ENV_OPTIONS = tuple(field.name for field in fields(EnvOptions))


def with_env_options(init: Callable[..., None]) -> Callable[..., None]:
    """``init`` (``PandaEnv.__init__``: its named parameters, then ``**options``) with a signature that names each
    env option instead: keyword-only, with its default and its type (without the checks), then
    ``**task_options`` for the rest.  ``help``, IDEs and ``inspect.signature`` read it."""
    signature = inspect.signature(init)
    named = [p for p in signature.parameters.values() if p.kind != inspect.Parameter.VAR_KEYWORD]
    types = get_type_hints(EnvOptions)  # Annotated stripped: the types a user passes
    env_options = [
        inspect.Parameter(f.name, inspect.Parameter.KEYWORD_ONLY, default=f.default, annotation=types[f.name])
        for f in fields(EnvOptions)
    ]
    task_options = inspect.Parameter("task_options", inspect.Parameter.VAR_KEYWORD, annotation=Any)
    init.__signature__ = signature.replace(parameters=[*named, *env_options, task_options])  # type: ignore[attr-defined]
    return init
