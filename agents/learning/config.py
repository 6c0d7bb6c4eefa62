"""Training configs and the envs they describe: a checked ``TrainConfig`` (YAML + ``key=value`` overrides), the
algorithm table, the policy's view of an observation, the training and evaluation envs, and what a resumed
run may change.  ``train.py`` and ``panda_grasp_env.agents.learning.training`` build runs from these."""

from __future__ import annotations

import inspect
from collections.abc import Callable
from pathlib import Path
from typing import Annotated, Any, Literal

import gymnasium as gym
import numpy as np
from pydantic import AfterValidator, ConfigDict, Field, StrictFloat, StrictInt, model_validator
from pydantic.dataclasses import dataclass

from panda_grasp_env.config_fields import Count, Seed, distinct
from panda_grasp_env.geometry import is_count, is_number
from panda_grasp_env.registration import ENV_IDS
from panda_grasp_env.tooling.reading import MAX_DOCUMENT_BYTES, read_yaml
from panda_grasp_env.tooling.runs import apply_key_values, check_resume_changes, checked_config, config_value_error

#: Algorithm name -> (SB3 class path, default policy).  ``heightmap_dqn`` is VPG-style DQN for the pixel mode.
ALGORITHMS: dict[str, tuple[str, str]] = {
    "heightmap_dqn": (
        "panda_grasp_env.agents.learning.heightmap_policy:HeightmapDQN",
        "panda_grasp_env.agents.learning.heightmap_policy:HeightmapQPolicy",
    ),
    # The same Q-policy on a goal heightmap, with hindsight goals and a block-count curriculum (goal_building.py).
    "goal_heightmap_dqn": (
        "panda_grasp_env.agents.learning.goal_building:GoalHeightmapDQN",
        "panda_grasp_env.agents.learning.heightmap_policy:HeightmapQPolicy",
    ),
    "sac": ("stable_baselines3:SAC", "MultiInputPolicy"),
    "tqc": ("sb3_contrib:TQC", "MultiInputPolicy"),
    "ppo": ("stable_baselines3:PPO", "MultiInputPolicy"),
    # Learning from demonstrations (agents/learning/imitation.py, heightmap_imitation.py); algo_kwargs.demonstrations
    # names the dataset.
    "bc": ("panda_grasp_env.agents.learning.imitation:BehaviourCloning", "MultiInputPolicy"),
    "tqc_demos": ("panda_grasp_env.agents.learning.imitation:TQCFromDemonstrations", "MultiInputPolicy"),
    "heightmap_dqn_demos": (
        "panda_grasp_env.agents.learning.heightmap_imitation:HeightmapDQNFromDemonstrations",
        "panda_grasp_env.agents.learning.heightmap_policy:HeightmapQPolicy",
    ),
}
#: The algorithms of the ``pixel`` mode's heightmap Q-policy (``panda_grasp_env.agents.learning.heightmap_policy``).
HEIGHTMAP_ALGORITHMS = ("heightmap_dqn", "heightmap_dqn_demos", "goal_heightmap_dqn")
#: The algorithms that learn without stepping an env: their steps are minibatches.
OFFLINE_ALGORITHMS = ("bc",)
#: The algorithms that learn from ``algo_kwargs.demonstrations``.
DEMONSTRATION_ALGORITHMS = ("bc", "tqc_demos", "heightmap_dqn_demos")
#: The algorithms that may use HER.
HER_ALGORITHMS = ("sac", "tqc", "tqc_demos")
#: The final test's seeds start this far above the validation seeds: choosing the best checkpoint on the
#: validation episodes does not flatter the reported figures.
TEST_SEED_OFFSET = 100_000
#: Episodes for choosing among runs or agent settings (``selection_episodes``, ``benchmarks/select_runs.py``) start this far above the
#: validation seeds: past the periodic validations, far below the test seeds.
SELECTION_SEED_OFFSET = 1_000
#: As many selection episodes as fit below the test seeds.
MOST_SELECTION_EPISODES = TEST_SEED_OFFSET - SELECTION_SEED_OFFSET

#: Training rewards: ``task`` is the env's own; ``outcome`` pays each primitive for what it achieved
#: (``OutcomeReward`` for a tower, ``goal_building.StructureOutcomeReward`` for a structure).
REWARDS = ("task", "outcome")


#: Keyword arguments for a constructor.
Keywords = Annotated[dict[str, Any], Field(description="a mapping")]


def registered_env_id(env_id: str) -> str:
    """``env_id`` if it is a registered id (tasks may register more after import); else ``ValueError``."""
    if env_id not in ENV_IDS:
        raise ValueError(f"one of {sorted(ENV_IDS)}")
    return env_id


@dataclass(frozen=True, config=ConfigDict(extra="forbid"))
class TrainConfig:
    """One training run.  Steps are environment steps (summed over ``n_envs``).

    A pydantic dataclass: each key's ``description`` says what values it takes, and ``config_from_dict`` quotes
    it in the ``ValueError`` of a bad value.  Keys that must agree are checked together after each alone.
    """

    name: Annotated[str, Field(pattern=r"^[\w-]*[^\W_][\w-]*$", description="letters, digits, - and _")]
    env_id: Annotated[str, AfterValidator(registered_env_id)]
    algo: Annotated[Literal[tuple(ALGORITHMS)], Field(description=f"one of {sorted(ALGORITHMS)}")]
    total_steps: Count
    env_kwargs: Keywords = Field(default_factory=dict)  # options for gymnasium.make
    # Added to env_kwargs in the training envs only (curricula such as start_in_hand); evaluation, the final
    # test and LearnedAgent use env_kwargs alone.
    train_env_kwargs: Keywords = Field(default_factory=dict)
    # None: the id's own limit
    max_episode_steps: Annotated[StrictInt | None, Field(gt=0, description="a positive int or null")] = None
    # The entries of a Dict observation the policy sees, e.g. [proprio, overhead_rgb, desired_goal] for a
    # policy that must see the objects through cameras (None: all of them).
    observation_keys: Annotated[
        Annotated[list[str], Field(min_length=1), AfterValidator(distinct)] | None,
        Field(description="null or a non-empty list of distinct observation entry names"),
    ] = None
    algo_kwargs: Keywords = Field(default_factory=dict)  # SB3 constructor arguments
    policy_kwargs: Keywords = Field(default_factory=dict)
    # HerReplayBuffer arguments; None = no HER
    her: Annotated[dict[str, Any] | None, Field(description="a mapping or null")] = None
    # What the learner is paid (evaluation always uses the task's metrics).
    reward: Annotated[Literal[REWARDS], Field(description=f"one of {list(REWARDS)}")] = "task"
    n_envs: Count = 1
    # subproc: the envs step in spawned worker processes
    vec_env: Annotated[Literal["dummy", "subproc"], Field(description="'dummy' or 'subproc'")] = "dummy"
    seed: Seed = 0
    eval_every: Count = 5000  # steps between evaluations
    eval_episodes: Count = 20
    # Validation episodes: seeds eval_seed, eval_seed + 1, ...; the final test: eval_seed + TEST_SEED_OFFSET, ...
    # (training episodes draw other seeds; see TrainConfig docs)
    eval_seed: Seed = 1_000_000
    final_eval_episodes: Count = 100
    # After training, the best periodic validation's policy and the final one each play this many episodes on
    # the selection seeds (eval_seed + SELECTION_SEED_OFFSET, ...) and the better of the two is tested; 0: the
    # validated best is tested unchecked.
    selection_episodes: Annotated[
        StrictInt,
        Field(
            ge=0,
            le=MOST_SELECTION_EPISODES,
            description=f"an int in [0, {MOST_SELECTION_EPISODES}] (clear of the test seeds)",
        ),
    ] = 0
    checkpoint_every: Count = 5000
    # Stop (and checkpoint) after this many minutes of wall time in total.
    max_minutes: Annotated[StrictInt | StrictFloat | None, Field(gt=0, description="a positive number or null")] = None
    torch_threads: Count = 1
    # A shipped checkpoint (name in agents/checkpoints, or folder) whose policy weights -- actor and critics --
    # start the run instead of random ones: fine-tuning after the task changed.  Same algorithm, spaces and
    # network; the optimisers, the entropy coefficient (set algo_kwargs.ent_coef) and the replay buffer start
    # afresh.  None: random weights.
    init_policy: Annotated[str | None, Field(description="a checkpoint name or folder, or null")] = None

    @model_validator(mode="after")
    def _check_keys_together(self) -> TrainConfig:
        def require(ok: bool, key: str, expected: str) -> None:
            if not ok:
                raise config_value_error(key, getattr(self, key), expected)

        require(
            self.observation_keys is None or (self.her is None and self.algo not in HEIGHTMAP_ALGORITHMS),
            "observation_keys",
            "null with HER (it needs achieved_goal) and with the heightmap algorithms",
        )
        require(
            self.her is None or self.algo in HER_ALGORITHMS, "her", f"null unless algo is one of {list(HER_ALGORITHMS)}"
        )
        task = ENV_IDS[self.env_id][0].get("task")
        require(
            self.reward == "task" or task in ("TowerBuild", "StructureBuild"),
            "reward",
            "'task' unless env_id is a TowerBuild or StructureBuild id (the outcome reward reads its progress)",
        )
        require(
            self.algo != "goal_heightmap_dqn" or (task == "StructureBuild" and self.reward == "outcome"),
            "algo",
            "goal_heightmap_dqn only on a StructureBuild id with reward: outcome (its hindsight goals need it)",
        )
        if self.algo in DEMONSTRATION_ALGORITHMS:
            from panda_grasp_env.agents.learning.imitation import Demonstrations

            require("demonstrations" in self.algo_kwargs, "algo_kwargs", f"a demonstrations entry for {self.algo}")
            Demonstrations.of(self.algo_kwargs["demonstrations"])
        rate = self.algo_kwargs.get("learning_rate")
        if isinstance(rate, dict):
            ok = rate.keys() == {"start", "end"} and all(is_number(v) and v >= 0 for v in rate.values())
            require(
                ok and rate["start"] > 0,
                "algo_kwargs",
                "learning_rate as a positive number or {start: > 0, end: >= 0} (linear over total_steps)",
            )
        valid = [p for p in constructor_parameters(load_class(ALGORITHMS[self.algo][0])) if p not in ("policy", "env")]
        unknown = [k for k in self.algo_kwargs if k not in valid or k in ("seed", "policy_kwargs", "tensorboard_log")]
        if unknown:
            raise ValueError(f"unknown algo_kwargs {unknown} for {self.algo}; valid: {sorted(valid)}")
        return self


def steps_label(config: TrainConfig) -> str:
    """What a run's steps count: environment steps, or minibatches for an offline algorithm."""
    return "minibatches (no environment steps)" if config.algo in OFFLINE_ALGORITHMS else "environment steps"


def constructor_parameters(cls: type) -> list[str]:
    """The keyword arguments ``cls(...)`` accepts: its ``__init__``'s, and where that passes ``**kwargs`` on, its
    bases' too."""
    names: list[str] = []
    for klass in cls.__mro__:
        if "__init__" not in vars(klass):
            continue
        parameters = inspect.signature(klass.__init__).parameters.values()
        names += [p.name for p in parameters if p.kind not in (p.VAR_KEYWORD, p.VAR_POSITIONAL) and p.name != "self"]
        if not any(p.kind == p.VAR_KEYWORD for p in parameters):
            break
    return list(dict.fromkeys(names))


def learning_rate(value: float | dict[str, float]) -> Any:
    """SB3's ``learning_rate`` from a config's: a number, or ``{start, end}`` for a linear decay from ``start``
    to ``end`` over the run's ``total_steps`` (SB3's progress is measured against them, also when resumed)."""
    from stable_baselines3.common.utils import LinearSchedule

    if isinstance(value, dict):
        return LinearSchedule(float(value["start"]), float(value["end"]), 1.0)
    return value


def load_class(path: str) -> Any:
    """A class of the ``ALGORITHMS`` table (``module:Class``); files never name what this imports."""
    import importlib

    module, name = path.split(":")
    return getattr(importlib.import_module(module), name)


def read_config(path: Path | str, overrides: list[str] | tuple[str, ...] = ()) -> dict[str, Any]:
    """A YAML config as a mapping, with ``key=value`` overrides applied (``apply_key_values``: values read as
    YAML, dotted keys reaching into mappings)."""
    path = Path(path)
    raw = read_yaml(path, MAX_DOCUMENT_BYTES) or {}  # a regular file, bounded: size, nesting, aliases (tooling.reading)
    if not isinstance(raw, dict):
        raise ValueError(f"config {path} must be a mapping of keys to values")
    return apply_key_values(raw, overrides, "override")


def load_config(path: Path | str, overrides: list[str] | tuple[str, ...] = ()) -> TrainConfig:
    """Read a YAML training config and apply overrides (``algo_kwargs.learning_rate=3e-4``); checked."""
    return config_from_dict(read_config(path, overrides), source=str(path))


def config_from_dict(raw: dict[str, Any], source: str = "config") -> TrainConfig:
    """The checked ``TrainConfig`` of a mapping; ``ValueError`` naming the bad key (``checked_config``)."""
    return checked_config(TrainConfig, raw, source)


# --- envs -------------------------------------------------------------------------------


def holding_plane(config: TrainConfig) -> bool:
    """Whether a heightmap policy sees the holding plane: it does when it may ``place``."""
    return config.algo in HEIGHTMAP_ALGORITHMS and "place" in config.policy_kwargs.get("primitives_used", ())


def observation_transform(config: TrainConfig) -> Callable[[Any, dict[str, Any]], Any]:
    """What the policy sees of an env observation and the step's info (the same in training, evaluation and
    ``LearnedAgent``)."""
    if config.algo in HEIGHTMAP_ALGORITHMS:
        from panda_grasp_env.agents.learning.heightmap_observations import encode_observation

        holding = holding_plane(config)
        return lambda observation, info: encode_observation(observation, info, holding)
    if config.observation_keys is not None:
        keys = config.observation_keys
        return lambda observation, info: {key: observation[key] for key in keys}
    return lambda observation, info: observation


def make_env(config: TrainConfig, render_mode: str | None = None, training: bool = False) -> gym.Env:
    """One env as the policy is evaluated on it, or with ``training`` as it is trained on it (with
    ``train_env_kwargs``); raw observations (see ``observation_transform``)."""
    import panda_grasp_env  # noqa: F401  (registers the ids)

    options = {**config.env_kwargs, **(config.train_env_kwargs if training else {})}
    if config.max_episode_steps is not None:
        options["max_episode_steps"] = config.max_episode_steps
    return gym.make(config.env_id, render_mode=render_mode, **options)


class OutcomeReward(gym.Wrapper):
    """Pays each tower-building primitive for what it achieved (VPG/SPOT style), for ``pixel`` actions on
    ``heightmap`` observations.

    A grasp earns 1 when it holds a block that lay on the table (the heightmap at the grasped cell under 1.5
    block sizes) other than the base; any step also earns the tower's change in height (levels, negative
    when it loses blocks) and 1 on success.  The task's own reward pays a block's grasp only once an
    episode, which a myopic learner (``gamma: 0``) that cannot see which blocks it grasped before reads as
    noise.  Paying every grasp needs the table rule: without it a policy learned to set a block on a loose
    one and grasp it back, +1 every other step.
    """

    def __init__(self, env: gym.Env) -> None:
        super().__init__(env)
        space = env.observation_space
        if not isinstance(env.action_space, gym.spaces.Discrete) or not (
            isinstance(space, gym.spaces.Box) and len(space.shape) == 3 and space.shape[-1] == 4
        ):
            raise ValueError(f"OutcomeReward needs action_mode='pixel' and obs_mode='heightmap'; got {space}")
        self._cells = space.shape[:2]

    def reset(self, **kwargs: Any) -> tuple[Any, dict[str, Any]]:
        observation, info = self.env.reset(**kwargs)
        if not {"stack_height", "base", "block_size"} <= set(info):
            raise ValueError("OutcomeReward needs a task that reports stack_height, base and block_size (TowerBuild)")
        self._levels, self._base, self._block = int(info["stack_height"]), info["base"], float(info["block_size"])
        self._heightmap = observation
        return observation, info

    def step(self, action: Any) -> tuple[Any, float, bool, bool, dict[str, Any]]:
        row, col = np.unravel_index(int(action) % (self._cells[0] * self._cells[1]), self._cells)
        from_table = self._heightmap[row, col, 3] < 1.5 * self._block
        observation, _, terminated, truncated, info = self.env.step(action)
        levels = int(info["stack_height"])
        reward = float(levels - self._levels) + float(bool(info["is_success"]))
        held = info.get("primitive") == "grasp" and info.get("primitive_success")
        if held and from_table and info.get("primitive_object") != self._base:
            reward += 1.0
        self._levels, self._heightmap = levels, observation
        return observation, reward, terminated, truncated, info


def training_env(config: TrainConfig) -> gym.Env:
    """The training env: ``make_env`` plus the training reward and the policy's observation wrapper."""
    import torch

    torch.set_num_threads(config.torch_threads)  # worker processes: never oversubscribe the cores
    env = make_env(config, training=True)
    if config.algo == "goal_heightmap_dqn" and config.env_kwargs.get("structure", "random") == "random":
        from panda_grasp_env.agents.learning.goal_building import BlockBudget

        env = BlockBudget(env)
    if config.reward == "outcome" and ENV_IDS[config.env_id][0].get("task") == "StructureBuild":
        from panda_grasp_env.agents.learning.goal_building import StructureOutcomeReward

        env = StructureOutcomeReward(env)
    elif config.reward == "outcome":
        env = OutcomeReward(env)
    if config.algo in HEIGHTMAP_ALGORITHMS:
        from panda_grasp_env.agents.learning.heightmap_observations import EncodedHeightmap

        env = EncodedHeightmap(env, holding_plane(config))
    if config.observation_keys is not None:
        spaces = getattr(env.observation_space, "spaces", {})
        missing = [key for key in config.observation_keys if key not in spaces]
        if missing:
            raise ValueError(
                f"observation_keys {missing} are not in {config.env_id}'s observations with "
                f"{config.env_kwargs} (its entries: {list(spaces)})"
            )
        env = gym.wrappers.FilterObservation(env, config.observation_keys)
    return env


def make_vec_env(config: TrainConfig) -> Any:
    """``n_envs`` training envs with SB3's ``Monitor``: in this process, or spawned workers (``vec_env: subproc``)."""
    from functools import partial

    from stable_baselines3.common.monitor import Monitor
    from stable_baselines3.common.vec_env import DummyVecEnv, SubprocVecEnv

    factories = [partial(lambda c: Monitor(training_env(c), info_keywords=("is_success",)), config)] * config.n_envs
    if config.vec_env == "subproc" and config.n_envs > 1:
        return SubprocVecEnv(factories, start_method="spawn")
    return DummyVecEnv(factories)


# --- model --------------------------------------------------------------------------------


#: What ``--resume`` may change: budgets, evaluation cadence and the learner's settings (``algo_kwargs``,
#: applied when SB3 loads the model).  Every other key built the saved networks, replay buffer or seeds.
RESUME_CHANGEABLE = (
    "total_steps",
    "max_minutes",
    "eval_every",
    "eval_episodes",
    "final_eval_episodes",
    "selection_episodes",
    "checkpoint_every",
    "torch_threads",
    "algo_kwargs",
)


def check_policy_resume(saved: TrainConfig, resumed: TrainConfig) -> None:
    """``ValueError`` naming the keys a resumed run changed that it cannot (see ``RESUME_CHANGEABLE``)."""
    before, after = saved.algo_kwargs.get("buffer_size"), resumed.algo_kwargs.get("buffer_size")
    # The saved buffer is loaded as it was; goal_heightmap_dqn grows it (GoalHeightmapDQN.load_replay_buffer).
    grows = resumed.algo == "goal_heightmap_dqn" and isinstance(after, int) and after > (before or 0)
    buffer_changed = before != after and not grows
    check_resume_changes(saved, resumed, RESUME_CHANGEABLE, ["algo_kwargs.buffer_size"] if buffer_changed else [])


#: Most bytes a run's replay or rollout buffer may take (SB3 allocates it whole when the model is built):
#: half of a 24 GiB machine.  The largest shipped run's takes 1.9 GB.
MAX_BUFFER_BYTES = 12 << 30


def space_bytes(space: gym.Space) -> int:
    """Bytes one value of ``space`` takes in an SB3 buffer (a Dict's parts summed; discrete actions as int64)."""
    if isinstance(space, gym.spaces.Dict):
        return sum(space_bytes(part) for part in space.spaces.values())
    if isinstance(space, gym.spaces.Discrete):
        return 8
    return int(np.prod(space.shape, dtype=object)) * np.dtype(space.dtype).itemsize


def check_buffer_bytes(config: TrainConfig, algo_class: type, env: Any, kwargs: dict[str, Any]) -> None:
    """``ValueError`` naming the setting before SB3 allocates a buffer of more than ``MAX_BUFFER_BYTES``: an
    off-policy run's ``buffer_size`` transitions (observation, next observation, action), or an on-policy run's
    ``n_steps`` x ``n_envs`` observations and actions."""
    from stable_baselines3.common.off_policy_algorithm import OffPolicyAlgorithm

    if config.algo in OFFLINE_ALGORITHMS:  # behaviour cloning keeps a one-transition buffer of its own
        return
    transition = space_bytes(env.observation_space) * 2 + space_bytes(env.action_space)
    if issubclass(algo_class, OffPolicyAlgorithm):
        setting, count = "algo_kwargs.buffer_size", kwargs.get("buffer_size", 1_000_000)
    else:
        setting, count = "algo_kwargs.n_steps", kwargs.get("n_steps", 2048) * env.num_envs
    if not is_count(count):
        return  # SB3 names a malformed value itself
    needed = count * transition
    if needed > MAX_BUFFER_BYTES:
        raise ValueError(
            f"{setting}={kwargs.get(setting.split('.')[-1], 'its default')}: a buffer of {count} transitions of "
            f"{transition} bytes takes {needed / 2**30:.1f} GiB, more than the {MAX_BUFFER_BYTES >> 30} GiB a run may"
        )


def algo_arguments(config: TrainConfig) -> dict[str, Any]:
    """The SB3 algorithm's keyword arguments from ``algo_kwargs`` (a ``{start, end}`` rate made a schedule)."""
    kwargs = dict(config.algo_kwargs)
    if "learning_rate" in kwargs:
        kwargs["learning_rate"] = learning_rate(kwargs["learning_rate"])
    return kwargs


def load_run(run_dir: Path) -> TrainConfig:
    """The resolved config of a run folder (its config.yaml); ``ValueError`` if it is not one."""
    if not (run_dir / "config.yaml").is_file():
        raise ValueError(f"{run_dir} is not a run folder (no config.yaml)")
    raw = read_yaml(run_dir / "config.yaml", MAX_DOCUMENT_BYTES)
    if not isinstance(raw, dict):
        raise ValueError(f"{run_dir / 'config.yaml'} must be a mapping of keys to values")
    return config_from_dict(raw, source=str(run_dir / "config.yaml"))
