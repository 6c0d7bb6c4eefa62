"""Learning to build any structure from its goal heightmap (``PandaStructure-v0``, ``structure="random"``).

Three pieces, each used by ``goal_heightmap_dqn`` (``configs/structure_builder_dqn.yaml``):

* ``structure_outcome``: what one primitive achieved toward a goal, computable for *any* goal from the pieces'
  poses before and after the step -- so a step can be paid again for a goal it was not aiming at.
  ``StructureOutcomeReward`` pays the env's goal with it.
* ``BlockBudget``: the training env's curriculum over block counts.  Each episode's structure is drawn from the
  generator with at most the current budget of pieces (half the episodes), or fewer.
* ``GoalHeightmapDQN``: the heightmap Q-learner with hindsight goals (HER's "future" strategy).  After each
  episode every step is stored again under goals the episode achieved later: the pieces it had moved by then,
  standing upright, drawn as a goal heightmap.  It also raises the budget once the last ``promote_window``
  episodes at the budget succeeded at least ``promote_at`` of the time.

World frame, metres, radians.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any

import gymnasium as gym
import numpy as np
import torch as th
from stable_baselines3.common.buffers import ReplayBuffer

from panda_grasp_env.agents.learning.heightmap_imitation import LargeMarginMixin
from panda_grasp_env.agents.learning.heightmap_observations import goal_plane, held_slot
from panda_grasp_env.agents.learning.heightmap_policy import HeightmapDQN
from panda_grasp_env.agents.policies.pixel_oracle import PixelPlaceOracle
from panda_grasp_env.model.structure_generator import random_structure
from panda_grasp_env.model.structures import BLOCK_KINDS, Piece
from panda_grasp_env.perception.heightmap import HeightmapGrid, heightmap_of_boxes
from panda_grasp_env.tasks.structure_build import (
    GOAL_FIELDS,
    TURN_TOLERANCE,
    goal_rows,
    match_goal,
    read_rows,
    resting_on,
)

#: A piece counts as moved by the episode (a hindsight goal may hold it) once its centre lies this far (metres)
#: from where it started.
MOVED = 0.02
#: A target rests on the table when its bottom lies this close to it (metres).
ON_TABLE = 0.005


def _rows(goal: np.ndarray) -> np.ndarray:
    """Goal-vector rows (slots, ``GOAL_FIELDS``) of a flat goal vector, those holding a piece only."""
    rows = np.asarray(goal, dtype=float).reshape(-1, GOAL_FIELDS)
    return rows[rows[:, 6] > 0.5]


def _pieces(rows: np.ndarray) -> list[Piece]:
    kinds, centres, headings = read_rows(rows)
    return [Piece(kind, tuple(centre), float(heading)) for kind, centre, heading in zip(kinds, centres, headings)]


def open_kinds(achieved: np.ndarray, desired: np.ndarray) -> set[int]:
    """Kind codes of the goal's open targets: held by no piece in ``achieved`` (``match_goal``) and supported --
    standing on the table, or on targets that are all held.  Rows as ``goal_rows``, pieces only."""
    filled = {target for target, _ in match_goal(achieved, desired)[0]}
    targets = _pieces(desired)
    kinds = set()
    for index, target in enumerate(targets):
        if index in filled:
            continue
        below = [i for i, other in enumerate(targets) if i != index and resting_on(other, [target])]
        on_table = target.position[2] - target.half_extents[2] < ON_TABLE
        if on_table or (below and all(i in filled for i in below)):
            kinds.add(int(round(desired[index, 6])))
    return kinds


def structure_outcome(before: np.ndarray, after: np.ndarray, desired: np.ndarray, grasped: int | None) -> float:
    """What one primitive achieved toward the ``desired`` goal, from the pieces' goal vectors ``before`` and
    ``after`` it (flat, ``goal_rows`` per object slot): the change in targets held (``match_goal``: +1 per target
    filled, -1 per target lost), +1 when every target is held after it, and +1 for a grasp that holds slot
    ``grasped`` when that piece held no target and a target of its kind was open (``open_kinds``).  Paying only
    useful grasps keeps a myopic learner (``gamma: 0``) from grasping a plank whose cubes are not yet built."""
    slots_before = np.asarray(before, dtype=float).reshape(-1, GOAL_FIELDS)
    achieved_before, achieved_after, goal = _rows(before), _rows(after), _rows(desired)
    pairs_before = match_goal(achieved_before, goal)[0]
    filled_after = len(match_goal(achieved_after, goal)[0])
    reward = float(filled_after - len(pairs_before)) + float(filled_after == len(goal))
    if grasped is not None and grasped < len(achieved_before):
        in_place = grasped in {piece for _, piece in pairs_before}
        if not in_place and int(round(slots_before[grasped, 6])) in open_kinds(achieved_before, goal):
            reward += 1.0
    return reward


def hindsight_goal(start: np.ndarray, achieved: np.ndarray, held: int | None) -> np.ndarray | None:
    """The structure an episode achieved by a step, as a desired goal vector (``goal_rows``, as many slots as
    ``achieved``): the pieces that moved from ``start`` (``MOVED``), stand upright and are not ``held``; None
    when there are none."""
    start_rows = np.asarray(start, dtype=float).reshape(-1, GOAL_FIELDS)
    rows = np.asarray(achieved, dtype=float).reshape(-1, GOAL_FIELDS)
    moved = np.linalg.norm(rows[:, :3] - start_rows[:, :3], axis=1) >= MOVED
    chosen = moved & (rows[:, 6] > 0.5) & (rows[:, 5] <= TURN_TOLERANCE)
    if held is not None and held < len(chosen):
        chosen[held] = False
    if not chosen.any():
        return None
    kinds, centres, headings = read_rows(rows[chosen])
    return goal_rows(kinds, centres, headings, np.zeros(len(kinds)), len(rows)).ravel()


def draw_goal(grid: HeightmapGrid, desired: np.ndarray) -> np.ndarray:
    """The goal heightmap (rows, cols, metres above the table) of a desired goal vector, as the task draws it."""
    kinds, centres, headings = read_rows(_rows(desired))
    halves = np.array([BLOCK_KINDS[kind] for kind in kinds]).reshape(-1, 3)
    return heightmap_of_boxes(grid, centres, halves, headings)


def _structure_task(env: gym.Env) -> Any:
    task = getattr(env.unwrapped, "task", None)
    if getattr(task, "name", None) != "StructureBuild":
        raise ValueError(f"this wrapper needs PandaStructure-v0 (StructureBuild), got {env.unwrapped.spec}")
    return task


class StructureOutcomeReward(gym.Wrapper):
    """Pays each primitive ``structure_outcome`` toward the env's goal, and leaves in ``info`` what hindsight
    relabelling and the teacher need: ``achieved_before``/``achieved_goal`` (the step's goal vectors before and
    after it; at reset, ``achieved_goal`` alone), ``desired_goal``, ``grasped_slot`` (the slot held after a
    successful grasp, else -1) and ``heightmap_grid`` (the grid's layout).  Needs a structure task with ``pixel`` actions on ``heightmap`` observations."""

    def __init__(self, env: gym.Env) -> None:
        super().__init__(env)
        _structure_task(env)
        spaces = getattr(env.observation_space, "spaces", {})
        if "goal_heightmap" not in spaces or not isinstance(env.action_space, gym.spaces.Discrete):
            raise ValueError(
                f"StructureOutcomeReward needs obs_mode='heightmap' and action_mode='pixel'; got {env.observation_space}"
            )
        self._achieved = np.zeros(0)
        self._grid: dict[str, Any] = {}

    def reset(self, **kwargs: Any) -> tuple[Any, dict[str, Any]]:
        observation, info = self.env.reset(**kwargs)
        self._achieved = np.asarray(observation["achieved_goal"], dtype=float)
        self._grid = dict(info["heightmap_grid"])
        return observation, {**info, **self._goals(observation)}

    @staticmethod
    def _goals(observation: dict[str, Any]) -> dict[str, np.ndarray]:
        return {
            "achieved_goal": np.asarray(observation["achieved_goal"], dtype=float),
            "desired_goal": observation["desired_goal"],
        }

    def step(self, action: Any) -> tuple[Any, float, bool, bool, dict[str, Any]]:
        observation, _, terminated, truncated, info = self.env.step(action)
        after = np.asarray(observation["achieved_goal"], dtype=float)
        slot = held_slot(info)
        reward = structure_outcome(self._achieved, after, observation["desired_goal"], slot)
        info = {
            **info,
            **self._goals(observation),
            "achieved_before": self._achieved,
            "grasped_slot": -1 if slot is None else slot,
            "heightmap_grid": self._grid,
        }
        self._achieved = after
        return observation, reward, terminated, truncated, info


class BlockBudget(gym.Wrapper):
    """Draws each episode's structure (``model.structure_generator.random_structure``, the task's tiers) with at
    most ``budget`` pieces: the budget itself half the time, else fewer (down to 2), so that what was learned on
    small structures keeps being practised.  ``set_block_budget`` moves it (2 to the scene's object slots);
    every step's ``info["block_budget"]`` is the budget the episode was drawn under."""

    def __init__(self, env: gym.Env, budget: int = 2) -> None:
        super().__init__(env)
        task = _structure_task(env)
        if task.fixed is not None:
            raise ValueError("BlockBudget draws structures: it needs structure='random'")
        self.most = int(task.n_slots)
        self.budget = self.most
        self.set_block_budget(budget)
        self._rng: np.random.Generator | None = None
        self._episode_budget = budget

    def set_block_budget(self, budget: int) -> None:
        if not (isinstance(budget, (int, np.integer)) and 2 <= budget <= self.most):
            raise ValueError(f"block budget must be an int in [2, {self.most}], got {budget!r}")
        self.budget = int(budget)

    def reset(self, *, seed: int | None = None, options: dict[str, Any] | None = None) -> tuple[Any, dict[str, Any]]:
        if seed is not None or self._rng is None:
            # The draw follows the episode seeds: a seeded reset starts the stream again.
            base = seed if seed is not None else int(self.env.unwrapped.np_random.integers(2**63))
            self._rng = np.random.default_rng([base, 7])
        options = dict(options or {})
        if "structure" not in options:
            budget = self.budget
            if budget > 2 and self._rng.random() < 0.5:
                budget = int(self._rng.integers(2, budget))
            options["structure"] = random_structure(self._rng, budget, self.env.unwrapped.task.tiers)
            self._episode_budget = budget
        observation, info = self.env.reset(seed=seed, options=options)
        return observation, {**info, "block_budget": self._episode_budget}

    def step(self, action: Any) -> tuple[Any, float, bool, bool, dict[str, Any]]:
        observation, reward, terminated, truncated, info = self.env.step(action)
        return observation, reward, terminated, truncated, {**info, "block_budget": self._episode_budget}


@dataclass
class _Step:
    observation: np.ndarray
    next_observation: np.ndarray
    action: np.ndarray
    before: np.ndarray
    after: np.ndarray
    grasped: int | None
    done: bool


class GoalHeightmapDQN(LargeMarginMixin, HeightmapDQN):
    """``HeightmapDQN`` on a goal-conditioned structure task, with hindsight goals and the block-count
    curriculum (module doc), and optionally a teacher.  Its training env is wrapped in
    ``StructureOutcomeReward`` and, where it draws random structures, ``BlockBudget``
    (``config.training_env``); on one fixed structure (BuilderBench's "training wheels") there is no curriculum.

    The teacher is the pixel-place oracle (``policies.pixel_oracle``), which reads the true poses: it plays the
    run's first ``teacher_episodes`` episodes in the training env, drawn at the whole block budget and stored
    like any others (relabelled too), then hands over.  No update is taken while it plays.  Its steps that were
    paid (a useful grasp, a filled target) are the demonstrations of DQfD's large-margin loss
    (``LargeMarginMixin``): ``pretrain_steps`` updates on the buffer come when it hands over, and a margin step
    follows every round of TD updates after.  They are found again in the replay buffer on ``--resume``, which
    therefore must never wrap (``buffer_size`` must hold the whole run).

    Args beyond DQN's:
        hindsight_goals: relabelled copies stored per step, each under a goal achieved at a later step of the
            same episode (uniform over the step itself and those after it).
        first_budget: the block budget the curriculum starts at.
        promote_at, promote_window: the budget rises by one once the last ``promote_window`` episodes drawn at
            it succeeded at least ``promote_at`` of the time.
        teacher_episodes: episodes the teacher plays first (0: none, and no margin loss).
        teacher_stride: the teacher aims at every ``teacher_stride``-th cell (2: the refined network's grid).
        margin, margin_weight, pretrain_steps, imitation_loss, temperature: the supervised loss on the
            teacher's paid steps, as ``heightmap_dqn_demos`` (``LargeMarginMixin``).
    """

    def __init__(
        self,
        *args: Any,
        hindsight_goals: int = 2,
        first_budget: int = 2,
        promote_at: float = 0.7,
        promote_window: int = 20,
        teacher_episodes: int = 0,
        teacher_stride: int = 2,
        margin: float = 0.2,
        margin_weight: float = 1.0,
        pretrain_steps: int = 0,
        imitation_loss: str = "margin",
        temperature: float = 0.05,
        **kwargs: Any,
    ) -> None:
        if not (isinstance(teacher_episodes, int) and teacher_episodes >= 0):
            raise ValueError(f"teacher_episodes must be an int >= 0, got {teacher_episodes!r}")
        self._set_margin("goal_heightmap_dqn", margin, margin_weight, pretrain_steps, imitation_loss, temperature)
        self.teacher_episodes, self.teacher_stride = teacher_episodes, teacher_stride
        self.teacher = PixelPlaceOracle(teacher_stride)  # checks the stride; made again by each learn
        #: Episodes the teacher has finished, the replay-buffer rows of its paid steps and, per row, the headings
        #: after which its action is the same again (the oracle's ``repeat_turn``); saved with the model.
        self.taught_episodes, self.taught_rows, self.taught_periods = 0, [], []
        if not (isinstance(hindsight_goals, int) and 0 <= hindsight_goals <= 8):
            raise ValueError(f"hindsight_goals must be an int in [0, 8], got {hindsight_goals!r}")
        if not (isinstance(first_budget, int) and first_budget >= 2):
            raise ValueError(f"first_budget must be an int of at least 2, got {first_budget!r}")
        if not (isinstance(promote_at, (int, float)) and 0 < promote_at <= 1):
            raise ValueError(f"promote_at must be a number in (0, 1], got {promote_at!r}")
        if not (isinstance(promote_window, int) and promote_window >= 1):
            raise ValueError(f"promote_window must be a positive int, got {promote_window!r}")
        self.hindsight_goals, self.promote_at, self.promote_window = hindsight_goals, float(promote_at), promote_window
        self.block_budget = first_budget
        self._budget_outcomes: list[bool] = []
        self._episodes: dict[int, list[_Step]] = {}
        super().__init__(*args, **kwargs)
        self._her_rng = np.random.default_rng(self.seed)
        self._teacher_plan_done = True

    def _excluded_save_params(self) -> list[str]:
        # An episode under way is not resumed (the env restarts), so its steps and the teacher's plan are not saved.
        return [*super()._excluded_save_params(), "_episodes", "teacher", "_teacher_plan_done"]

    def load_replay_buffer(self, path: Any, truncate_last_traj: bool = True) -> None:
        """SB3's, and a buffer saved smaller than ``buffer_size`` (a resumed run given more steps) is grown to it,
        its rows kept where they were (the teacher's rows are found by index)."""
        super().load_replay_buffer(path, truncate_last_traj)
        saved = self.replay_buffer
        if saved.buffer_size >= self.buffer_size:
            return
        if saved.full:
            raise ValueError(
                f"goal_heightmap_dqn: the saved replay buffer has wrapped; it cannot grow to {self.buffer_size}"
            )
        grown = type(saved)(
            self.buffer_size,
            saved.observation_space,
            saved.action_space,
            device=saved.device,
            n_envs=saved.n_envs,
            handle_timeout_termination=saved.handle_timeout_termination,
        )
        for name in ("observations", "next_observations", "actions", "rewards", "dones", "timeouts"):
            getattr(grown, name)[: saved.pos] = getattr(saved, name)[: saved.pos]
        grown.pos = saved.pos
        self.replay_buffer = grown

    @property
    def teaching(self) -> bool:
        """Whether the teacher plays the episode under way."""
        return self.taught_episodes < self.teacher_episodes

    def _curriculum(self) -> bool:
        """Whether the training env draws its structures (``BlockBudget``): not on one fixed structure."""
        return self.env is not None and self.env.has_attr("set_block_budget")

    def _setup_learn(
        self, total_timesteps: int, callback: Any = None, reset_num_timesteps: bool = True, *args: Any, **kwargs: Any
    ) -> Any:
        # SB3 restarts the env on a fresh count or a loaded model; a later learn() goes on with the episode.
        fresh_episode = reset_num_timesteps or self._last_obs is None
        self._episodes = {}
        if self.teaching and self.n_envs != 1:
            raise ValueError(f"goal_heightmap_dqn: the teacher plays one env, got n_envs {self.n_envs}")
        if self._curriculum():
            self.block_budget = min(self.block_budget, max(self.env.get_attr("most")))
            self.env.env_method(
                "set_block_budget", max(self.env.get_attr("most")) if self.teaching else self.block_budget
            )
        result = super()._setup_learn(total_timesteps, callback, reset_num_timesteps, *args, **kwargs)
        ahead = (result[0] - self.num_timesteps) * (1 + self.hindsight_goals)
        if self.teacher_episodes and self.replay_buffer.size() + ahead > self.replay_buffer.buffer_size:
            raise ValueError(
                f"goal_heightmap_dqn: a replay buffer of {self.replay_buffer.buffer_size} cannot keep its "
                f"{self.replay_buffer.size()} rows and the run's {ahead} to come (steps and their "
                f"{self.hindsight_goals} relabelled copies each): the teacher's rows are found in it again"
            )
        if self.taught_rows:
            self.keep_taught()
        if fresh_episode:
            self.teacher = PixelPlaceOracle(self.teacher_stride)
            self._start_teacher(self.env.reset_infos[0])
        return result

    def _start_teacher(self, info: dict[str, Any]) -> None:
        if self.teaching:
            self.teacher.start(info["desired_goal"], info["action_layout"], int(info["n_targets"]))
            self._teacher_achieved, self._teacher_plan_done = info["achieved_goal"], False

    def _sample_action(
        self, learning_starts: int, action_noise: Any = None, n_envs: int = 1
    ) -> tuple[np.ndarray, np.ndarray]:
        if self.teaching and not self._teacher_plan_done:
            action = self.teacher.next_action(self._teacher_achieved)
            if action is not None:
                return np.array([action]), np.array([action])
            self._teacher_plan_done = True  # a failed plan: the learner plays the episode out
        return super()._sample_action(learning_starts, action_noise, n_envs)

    def train(self, gradient_steps: int, batch_size: int = 100) -> None:
        if self.teaching:
            return
        if self.teacher_episodes:
            self._pretrain()
            self._update(gradient_steps, batch_size)
        else:
            HeightmapDQN.train(self, gradient_steps, batch_size)

    def _store_transition(
        self,
        replay_buffer: ReplayBuffer,
        buffer_action: np.ndarray,
        new_obs: Any,
        reward: np.ndarray,
        dones: np.ndarray,
        infos: list[dict[str, Any]],
    ) -> None:
        observations = np.array(self._last_obs)
        super()._store_transition(replay_buffer, buffer_action, new_obs, reward, dones, infos)
        if self.teaching and not self._teacher_plan_done and reward[0] > 0:
            self.taught_rows.append((replay_buffer.pos - 1) % replay_buffer.buffer_size)
            headings = self.q_net.rotations * self.teacher.repeat_turn / (2 * np.pi)
            whole = abs(headings - round(headings)) < 1e-6
            self.taught_periods.append(int(round(headings)) if whole else self.q_net.rotations)
        for env_index, info in enumerate(infos):
            done = bool(dones[env_index])
            following = info.get("terminal_observation") if done else None
            step = _Step(
                observation=observations[env_index],
                next_observation=np.array(new_obs[env_index] if following is None else following),
                action=np.array(buffer_action[env_index]),
                before=info["achieved_before"],
                after=info["achieved_goal"],
                grasped=None if info["grasped_slot"] < 0 else int(info["grasped_slot"]),
                done=done and not info.get("TimeLimit.truncated", False),
            )
            episode = self._episodes.setdefault(env_index, [])
            episode.append(step)
            if done:
                self._relabel(replay_buffer, episode, HeightmapGrid.of_layout(info["heightmap_grid"]))
                self._episodes[env_index] = []
                if self.teaching:
                    self._finish_teaching_episode()
                else:
                    self._follow_curriculum(info)
            elif self.teaching:
                self._teacher_achieved = info["achieved_goal"]

    def _finish_teaching_episode(self) -> None:
        self.taught_episodes += 1
        if self.teaching:
            self._start_teacher(self.env.reset_infos[0])
            return
        if not self.taught_rows:
            raise ValueError("goal_heightmap_dqn: the teacher's episodes were never paid, nothing to learn from")
        self.keep_taught()
        if self._curriculum():
            self.env.env_method("set_block_budget", self.block_budget)

    def keep_taught(self, first: int | None = None) -> None:
        """The teacher's paid steps (its ``first`` ones, or all), found in the replay buffer, are the margin
        loss's demonstrations."""
        rows = np.array(self.taught_rows[:first])
        self._keep_demonstrations(self.replay_buffer.observations[rows, 0], self.replay_buffer.actions[rows, 0, 0])
        # A run from before the periods were recorded has none: the margin loss's default then.
        self._demo_periods = th.as_tensor(self.taught_periods[:first]) if self.taught_periods else None

    def _relabel(self, replay_buffer: ReplayBuffer, episode: list[_Step], grid: HeightmapGrid) -> None:
        """Store each step again under ``hindsight_goals`` goals the episode achieved at that step or later."""
        plane = self.q_net.goal_plane
        start = episode[0].before
        drawn: dict[int, tuple[np.ndarray, np.ndarray] | None] = {}
        for index, step in enumerate(episode):
            for _ in range(self.hindsight_goals):
                later = int(self._her_rng.integers(index, len(episode)))
                if later not in drawn:
                    goal = hindsight_goal(start, episode[later].after, episode[later].grasped)
                    drawn[later] = None if goal is None else (goal, goal_plane(draw_goal(grid, goal)))
                if drawn[later] is None:
                    continue
                goal, image = drawn[later]
                observation, following = step.observation.copy(), step.next_observation.copy()
                observation[plane], following[plane] = image, image
                reward = structure_outcome(step.before, step.after, goal, step.grasped)
                replay_buffer.add(
                    observation[None],
                    following[None],
                    step.action[None],
                    np.array([reward], dtype=np.float32),
                    np.array([step.done]),
                    [{}],
                )

    def _follow_curriculum(self, info: dict[str, Any]) -> None:
        if not self._curriculum() or info.get("block_budget") != self.block_budget:
            return
        self._budget_outcomes = [*self._budget_outcomes, bool(info.get("is_success"))][-self.promote_window :]
        most = max(self.env.get_attr("most"))
        full = len(self._budget_outcomes) == self.promote_window
        if full and np.mean(self._budget_outcomes) >= self.promote_at and self.block_budget < most:
            self.block_budget += 1
            self._budget_outcomes = []
            self.env.env_method("set_block_budget", self.block_budget)
        self.logger.record("curriculum/block_budget", self.block_budget)
