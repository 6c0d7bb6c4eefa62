"""``PandaEnv``: the one Gymnasium env.  It joins a workcell, a task, an action mode and observations.

The step loop (``PandaEnv.step``) reads top to bottom: validate the action,
execute it (one primitive, or one 25 Hz control step), let the task judge the
result, count, observe.  Tasks live in ``panda_grasp_env/tasks`` (one file
each), action modes in ``actions.py``, observations in ``observations.py``, env
options (declared once, checked) in ``env_options.py``, where the hand starts in ``sim/starts.py``, render modes in ``sim/rendering.py``.
"""

from __future__ import annotations

from typing import Any

import gymnasium as gym
import numpy as np

from panda_grasp_env.actions import EE_STEP, LOW_LEVEL_BOUNDS, ActionMode
from panda_grasp_env.control.controller import ControllerLimits
from panda_grasp_env.env_options import ENV_OPTIONS, EnvOptions, with_env_options
from panda_grasp_env.model.robot import HOME_YAW
from panda_grasp_env.model.scene import CAMERA_NAMES
from panda_grasp_env.observations import ObservationBuilder, Sensors
from panda_grasp_env.perception.camera import CameraModel
from panda_grasp_env.primitives.registry import COUNTERS, count
from panda_grasp_env.randomization import DomainRandomizer
from panda_grasp_env.registration import make_task
from panda_grasp_env.sim.rendering import RENDER_MODES, EnvRenderer, advertised_render_modes
from panda_grasp_env.sim.starts import start_hand
from panda_grasp_env.sim.stepping import PhysicsError
from panda_grasp_env.sim.workcell import Workcell
from panda_grasp_env.tasks import TaskStep


class PandaEnv(gym.Env):
    """A Franka Panda building, breaking and grasping in MuJoCo.

    Args:
        task: a registered task's name (``TowerBuild``, ``TowerBreak``, ``BuildAndBreak``, ``Grasp``, ``Push``,
            ``PutInBin``, or one of your own: ``registration.TASKS``).
        **options: by keyword, the env options and the task's options.  The env options (``obs_mode``,
            ``action_mode``, ``render_mode``, cameras, sizes, scene, curricula, randomisation, reward type) are
            the fields of [`EnvOptions`][panda_grasp_env.env_options.EnvOptions], each with its default and what
            it does; the others are passed to the task (see each task's docstring).
    """

    # The class names every mode, "human" included: ``gymnasium.make`` reads the class's metadata, and where
    # "human" is missing it wraps an ``rgb_array`` env in its pygame ``HumanRendering`` instead of passing the
    # mode on, so the env's own refusal without a display would never run.  An instance advertises the modes
    # that work here (``advertised_render_modes``), which is what checkers read.
    metadata = {"render_modes": list(RENDER_MODES), "render_fps": 25}

    @with_env_options  # the signature names each env option, read from ``EnvOptions``
    def __init__(self, task: str = "TowerBuild", **options: Any) -> None:
        task_options = {name: value for name, value in options.items() if name not in ENV_OPTIONS}
        try:
            self.task = make_task(task, task_options)
        except ValueError as error:
            raise ValueError(f"{error}; env options: {['task', *ENV_OPTIONS]}") from None
        #: The env options, checked (``EnvOptions``).
        self.options = env_options = EnvOptions.checked(
            self.task, **{name: value for name, value in options.items() if name in ENV_OPTIONS}
        )
        self.metadata = {**PandaEnv.metadata, "render_modes": advertised_render_modes()}
        self.obs_mode, self.action_mode = env_options.obs_mode, env_options.action_mode
        self.render_mode, self.render_size = env_options.render_mode, env_options.render_size
        self.reward_type = env_options.reward_type
        #: Start state -> probability of an episode starting there (a training curriculum; empty: none).
        self.start_curriculum = env_options.start_curriculum
        mode = env_options.mode
        #: Whether the agent sees and is rewarded by goals: a goal-conditioned task in a low-level mode, or in
        #: any mode where the task says so (``Task.goals_in_every_mode``).
        self.goal_conditioned = self.task.goal_conditioned and (mode.low_level or self.task.goals_in_every_mode)
        self.task.fixed_hand_yaw = HOME_YAW if mode.fixed_hand_yaw else None
        # Low-level modes let the reference move EE_STEP per control step; primitives keep their own speeds.
        limits = ControllerLimits(linear_speed=EE_STEP / 0.04) if mode.low_level else None
        self.cell = Workcell(env_options.scene_config(self.task), limits=limits)
        self.cell.physics.add_observer(self.task.on_control_step)
        # The callbacks below capture the sensors, not the env: the env then forms no reference cycle and is
        # freed as soon as it is dropped (``sim.parts``).
        self.sensors = sensors = Sensors(self.cell, env_options.image_size, env_options.grid)
        context = env_options.action_context(self.task, self.cell, lambda: sensors.heightmap()[0])
        self.actions: ActionMode = mode.build(context)
        if self.goal_conditioned:
            # Only goal envs have compute_reward (vectorised, for HER): checkers treat its presence as "GoalEnv".
            self.compute_reward = self.task.compute_reward if self.reward_type == "sparse" else self.task.dense_reward
        self._goal_in_state = self.task.goal_conditioned and not self.goal_conditioned  # at the state vector's end
        goal_size = self.task.goal_size if self.goal_conditioned else None
        extra_size = self.task.properties_size + (self.task.goal_size if self._goal_in_state else 0)
        drawing = None if goal_size is None else self.task.goal_heightmap  # the goal beside the heightmap
        sizes = (goal_size, extra_size, self.task.command_size, drawing)
        self.observations = ObservationBuilder(
            self.cell, env_options.modalities, env_options.cameras, self.sensors, *sizes
        )
        self.action_space = self.actions.space
        self.observation_space = self.observations.space
        self.randomizer = (
            None if env_options.randomization is None else DomainRandomizer(env_options.randomization, self.cell)
        )
        if self.randomizer is not None:
            self.observations.depth_filter = self.randomizer.noisy_depth
        self.renderer = EnvRenderer(
            self.cell,
            self.render_mode,
            env_options.render_size,
            self.metadata["render_fps"],
            lambda: sensors.rgbd("front", *env_options.render_size)[1],
        )
        if self.render_mode == "rgb_array_list":  # frames inside primitives too
            self.cell.physics.add_observer(self.renderer.on_control_step)
        self._counters = dict.fromkeys(COUNTERS, 0)
        self._clipped_total = 0

    # --- the step loop -----------------------------------------------------------
    def reset(self, *, seed: int | None = None, options: dict[str, Any] | None = None) -> tuple[Any, dict[str, Any]]:
        super().reset(seed=seed)
        if options is not None and not isinstance(options, dict):
            raise ValueError(f"reset options must be a dict or None, got {type(options).__name__}")
        unknown = sorted(set(options or {}) - set(self.task.reset_options))
        if unknown:
            raise ValueError(
                f"unknown reset option(s) {unknown}; {self.task.name} takes {list(self.task.reset_options)}"
            )
        self.task.apply_reset_options(self.cell, dict(options or {}))
        self.renderer.pause()  # rgb_array_list: no frames of the scene being laid out and settled
        if self.randomizer is not None:
            self.randomizer.restore()  # the task lays out its scene on the nominal model
        rng = self._episode_stream()
        task_info = self.task.reset(self.cell, rng)
        start = "ready"
        if self.actions.low_level:
            start = start_hand(
                self.cell, self.start_curriculum, self.task.start_object, rng, LOW_LEVEL_BOUNDS, self.task.desired_goal
            )
        self.actions.reset(self.cell, rng)
        if self.randomizer is not None:  # drawn last: the scene and the rest of the stream are as without it
            task_info["randomization"] = self.randomizer.apply(rng)
        self.sensors.invalidate()
        self._counters = dict.fromkeys(COUNTERS, 0)
        self._clipped_total = 0
        info = {
            "is_success": False,
            **task_info,
            **self._counters,
            "physics_error": False,
            "sim_time": 0.0,
            **self._published_facts(),
        }
        if self.start_curriculum:
            info["start"] = start
        self.renderer.start_episode()  # rgb_array_list: the list starts at the reset state
        return self._observe(), info

    def _episode_stream(self) -> np.random.Generator:
        """The generator an episode's reset draws from (layout, start state, planner seed, randomisation): a
        child spawned from ``np_random``'s seed sequence.  Never ``np_random``'s own first draws: Gymnasium
        seeds an action space given the same integer (``action_space.seed(s)``) from the same
        ``SeedSequence(s)``, so a random agent seeded the usual way would repeat the scene's draws -- and aim
        its first push at the tower.  Each reset spawns the next child, so episodes after a seeded reset
        differ and stay reproducible."""
        return self.np_random.spawn(1)[0]

    def step(self, action: Any) -> tuple[Any, float, bool, bool, dict[str, Any]]:
        command, clipped = self.actions.validate(action)
        self._clipped_total += clipped
        result, verdict = None, None
        try:
            result = self.actions.execute(self.cell, command)
            physics_error = result is not None and result.reason == "physics_error"
            if not physics_error:
                verdict = self.task.evaluate(self.cell, result)  # may move things too (Grasp sets objects aside)
        except PhysicsError:
            physics_error = True
        if verdict is None:  # a diverged step earns nothing (sparse goal rewards: -1, since 0 is success)
            verdict = TaskStep(-1.0 if self.goal_conditioned else 0.0, False, False)
        self.sensors.invalidate()
        if result is not None:
            count(result, self._counters)
        info = {
            "is_success": verdict.success,
            **verdict.info,
            **(result.info() if result is not None else {}),
            **self._counters,
            "actions_clipped": clipped,
            "actions_clipped_total": self._clipped_total,
            "physics_error": physics_error,
            "sim_time": self.cell.sim_time,
        }
        self.renderer.show()
        truncated = physics_error or verdict.truncated
        observation, reward = self._observe(physics_error), verdict.reward
        if self.reward_type == "dense" and not physics_error:  # from the goals the learner sees, as HER will
            reward = float(self.compute_reward(observation["achieved_goal"], observation["desired_goal"], info))
        return observation, reward, verdict.terminated, truncated, info

    # --- helpers ------------------------------------------------------------------
    def _published_facts(self) -> dict[str, Any]:
        """What an agent may know besides the observation: the action layout, the cameras, the blocks."""
        facts: dict[str, Any] = {
            "camera_models": {camera: self.camera_model(camera) for camera in self.observations.cameras},
            "block_size": self.cell.config.block_size,
            "block_colours": dict(zip(self.cell.block_names, self.cell.config.colours.values())),
        }
        if "heightmap" in self.observations.modalities:  # the grid the heightmap observations lie on
            facts["heightmap_grid"] = self.sensors.grid.layout()
        layout = self.actions.layout()
        if layout is not None:
            facts["action_layout"] = layout
        return facts

    def _observe(self, sanitise: bool = False) -> Any:
        extra = None
        if self.observations.extra_size:
            extra = np.concatenate([self.task.properties(), self.task.desired_goal() if self._goal_in_state else []])
        goals = (self.task.achieved_goal(self.cell), self.task.desired_goal()) if self.goal_conditioned else None
        observation = self.observations.observe(goals, extra, self.task.command())
        if sanitise:  # after a divergence the state may hold NaN: never hand that to a learner
            if isinstance(observation, dict):
                return {k: np.nan_to_num(v, posinf=0.0, neginf=0.0) for k, v in observation.items()}
            return np.nan_to_num(observation, posinf=0.0, neginf=0.0)
        return observation

    # --- public extras --------------------------------------------------------------
    def action_masks(self) -> np.ndarray:
        """Allowed actions of the ``pixel`` mode, or of each dimension of ``pixel_factored`` (for sb3-contrib's
        MaskablePPO)."""
        if not hasattr(self.actions, "action_masks"):
            raise ValueError(f"action_masks is defined for the pixel action modes only, not {self.action_mode!r}")
        return self.actions.action_masks(holding=self.cell.robot.body_between_fingers() is not None)

    def camera_model(
        self, camera: str = "overhead", width: int | None = None, height: int | None = None
    ) -> CameraModel:
        """Pinhole model (intrinsics, pose) of a camera as it is now, for image sizes of the observations by default."""
        if camera not in CAMERA_NAMES:
            raise ValueError(f"unknown camera {camera!r}; valid: {list(CAMERA_NAMES)}")
        return self.sensors.camera_model(camera, width, height)

    # --- rendering ------------------------------------------------------------------
    def render(self) -> np.ndarray | list[np.ndarray] | None:
        """The ``render_mode``'s frame, or its frames since the last call (``rgb_array_list``); see ``EnvRenderer``."""
        if self.render_mode is None:
            gym.logger.warn("render() called without a render_mode; pass render_mode= to make()")
            return None
        return self.renderer.render()

    def close(self) -> None:
        self.sensors.close()
        self.renderer.close()
