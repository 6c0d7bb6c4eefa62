"""Learning from demonstrations: episodes recorded as Minari datasets (``agents/learning/demonstrations.py``)
into SB3 policies, through ``train.py`` like any other algorithm.

* ``bc`` -- ``BehaviourCloning``: supervised regression of a SAC policy's deterministic action onto the
  demonstrated actions.  It never steps an env to learn; its "steps" are minibatches.
* ``tqc_demos`` -- ``TQCFromDemonstrations``: TQC (+ HER) with the demonstrations in its replay buffer and,
  after every update, a behaviour-cloning step on the actor filtered by the critic (Nair et al. 2018, "Overcoming
  exploration in reinforcement learning with demonstrations": a demonstrated action is imitated only where the
  critic rates it above the policy's own).
* ``heightmap_dqn_demos`` -- ``heightmap_imitation.HeightmapDQNFromDemonstrations``: the ``pixel`` mode's
  heightmap DQN with the demonstrations in its replay buffer and a large-margin loss that ranks the demonstrated
  action first (DQfD).

All read ``algo_kwargs.demonstrations``: ``{dataset, episodes, path, successful_only}`` (``Demonstrations``).
"""

from __future__ import annotations

from abc import ABC, abstractmethod
from dataclasses import dataclass, fields
from pathlib import Path
from typing import Any

import gymnasium as gym
import numpy as np
import torch
from sb3_contrib import TQC
from stable_baselines3 import SAC
from torch.nn import functional

from panda_grasp_env.agents.learning.datasets import dataset_metadata, open_dataset
from panda_grasp_env.geometry import is_count, is_number


@dataclass(frozen=True)
class Demonstrations:
    """The demonstrations a run learns from: the first ``episodes`` episodes (in recorded order; with
    ``successful_only``, the first that end in success) of the Minari dataset ``dataset`` under ``path``."""

    dataset: str
    episodes: int
    path: str = "data/minari"
    successful_only: bool = True

    @classmethod
    def of(cls, value: Any) -> Demonstrations:
        """``value`` (a mapping of the fields) checked; ``ValueError`` naming what is wrong."""
        names = [f.name for f in fields(cls)]
        if not isinstance(value, dict) or not {"dataset", "episodes"} <= set(value) or set(value) - set(names):
            raise ValueError(
                f"demonstrations must be a mapping with keys dataset, episodes (and optionally path, "
                f"successful_only), got {value!r}"
            )
        spec = cls(**value)
        whole = isinstance(spec.episodes, int) and not isinstance(spec.episodes, bool)
        if not (whole and spec.episodes >= 1):
            raise ValueError(f"demonstrations.episodes must be an int >= 1, got {spec.episodes!r}")
        if not isinstance(spec.dataset, str) or not isinstance(spec.path, str):
            raise ValueError(f"demonstrations.dataset and .path must be strings, got {spec.dataset!r}, {spec.path!r}")
        if not isinstance(spec.successful_only, bool):
            raise ValueError(f"demonstrations.successful_only must be a bool, got {spec.successful_only!r}")
        return spec

    def data_folder(self) -> Path:
        """The dataset's data folder, its ``metadata.json`` checked (``datasets.dataset_metadata``): ``ValueError``
        if the dataset is missing or its metadata is refused (``train.py`` asks before it makes a run folder)."""
        folder = Path(self.path) / self.dataset / "data"
        if not folder.is_dir():
            raise ValueError(
                f"demonstrations: no Minari dataset {self.dataset!r} under {self.path} (record it with "
                f"python -m panda_grasp_env.agents.learning.demonstrations)"
            )
        dataset_metadata(folder)
        return folder

    def episodes_data(self) -> list[Any]:
        """The chosen episodes (Minari ``EpisodeData``), in recorded order; ``ValueError`` if the dataset is
        missing, holds too few, or is not data alone (``datasets.open_dataset``)."""
        chosen = []
        for episode in open_dataset(self.data_folder()).iterate_episodes():
            success = bool(np.asarray(episode.infos.get("is_success", [False]))[-1]) if episode.infos else False
            if success or not self.successful_only:
                chosen.append(episode)
            if len(chosen) == self.episodes:
                return chosen
        raise ValueError(
            f"demonstrations: {self.dataset} holds only {len(chosen)} "
            f"{'successful ' if self.successful_only else ''}episodes, {self.episodes} asked for"
        )

    def transitions(
        self, space: gym.Space, episodes: list[Any] | None = None
    ) -> tuple[dict[str, np.ndarray] | np.ndarray, np.ndarray]:
        """(observations, actions) of every step of ``episodes`` (default: ``episodes_data()``), the
        observations checked against the env's observation ``space`` (a ``Dict`` of boxes or a box)."""
        episodes = self.episodes_data() if episodes is None else episodes
        if isinstance(space, gym.spaces.Dict):
            observations = {}
            for key, box in space.spaces.items():
                if any(key not in e.observations for e in episodes):
                    raise ValueError(
                        f"demonstrations {self.dataset}: no observation {key!r} (the env's: {list(space.spaces)})"
                    )
                observations[key] = np.concatenate([e.observations[key][:-1] for e in episodes]).astype(box.dtype)
                if observations[key].ndim == 4 and observations[key].shape[1:] == (*box.shape[1:], box.shape[0]):
                    observations[key] = observations[key].transpose(0, 3, 1, 2)  # SB3 sees images channel-first
                if observations[key].shape[1:] != box.shape:
                    raise ValueError(
                        f"demonstrations {self.dataset}: observation {key!r} has shape "
                        f"{observations[key].shape[1:]}, the env's {box.shape}"
                    )
        else:
            observations = np.concatenate([e.observations[:-1] for e in episodes]).astype(np.float32)
            if observations.shape[1:] != space.shape:
                raise ValueError(
                    f"demonstrations {self.dataset}: observations of shape {observations.shape[1:]}, "
                    f"the env's {space.shape}"
                )
        actions = np.concatenate([e.actions for e in episodes]).astype(np.float32)
        return observations, actions


def _tensors(observations: dict[str, np.ndarray] | np.ndarray, device: torch.device) -> Any:
    if isinstance(observations, dict):
        return {key: torch.as_tensor(value, device=device) for key, value in observations.items()}
    return torch.as_tensor(observations, device=device)


def _noisy(observations: Any, std: float, generator: torch.Generator) -> Any:
    def noisy(value: torch.Tensor) -> torch.Tensor:
        if not value.dtype.is_floating_point:  # images: uint8 pixels stay as they are
            return value
        return value + std * torch.randn(value.shape, generator=generator).to(value.device)

    if isinstance(observations, dict):
        return {key: noisy(value) for key, value in observations.items()}
    return noisy(observations)


def _shifted(observations: Any, pad: int, generator: torch.Generator) -> Any:
    """Each (batch, channels, height, width) uint8 image entry shifted by up to ``pad`` pixels each way."""

    def shift(images: torch.Tensor) -> torch.Tensor:
        if images.ndim != 4 or images.dtype != torch.uint8:
            return images
        batch, channels, height, width = images.shape
        padded = functional.pad(images.float(), (pad, pad, pad, pad), mode="replicate")
        dy, dx = (torch.randint(0, 2 * pad + 1, (2, batch), generator=generator)).to(images.device)
        rows = (torch.arange(height, device=images.device)[None, :] + dy[:, None])[:, None, :, None]
        cols = (torch.arange(width, device=images.device)[None, :] + dx[:, None])[:, None, None, :]
        samples = torch.arange(batch, device=images.device)[:, None, None, None]
        planes = torch.arange(channels, device=images.device)[None, :, None, None]
        return padded[samples, planes, rows, cols].to(torch.uint8)

    if isinstance(observations, dict):
        return {key: shift(value) for key, value in observations.items()}
    return shift(observations)


def _rows(observations: Any, index: torch.Tensor) -> Any:
    if isinstance(observations, dict):
        return {key: value[index] for key, value in observations.items()}
    return observations[index]


def _stacked(episodes: list[Any], step: int, space: gym.Space) -> Any:
    """The observations of ``episodes`` at ``step``, stacked as a vectorised env returns them."""
    if isinstance(space, gym.spaces.Dict):
        return {key: np.stack([e.observations[key][step] for e in episodes]) for key in space.spaces}
    return np.stack([e.observations[step] for e in episodes])


class DemonstrationMixin:
    """Loads ``demonstrations`` when the model is set up (also after ``load``: they are never saved with the
    model) and draws random minibatches of them (seeded by the model's seed; a resumed run draws afresh)."""

    _demo_observations: Any
    _demo_actions: torch.Tensor

    def _setup_demonstrations(self) -> list[Any]:
        """Read the demonstrations into tensors; returns their episodes (Minari ``EpisodeData``)."""
        spec = Demonstrations.of(self.demonstrations)
        episodes = spec.episodes_data()
        observations, actions = spec.transitions(self.observation_space, episodes)
        if actions.shape[1:] != self.action_space.shape:
            raise ValueError(
                f"demonstrations {spec.dataset}: actions of shape {actions.shape[1:]}, the env's "
                f"{self.action_space.shape}"
            )
        self._keep_demonstrations(observations, np.clip(actions, -1.0, 1.0))
        return episodes

    def _keep_demonstrations(self, observations: dict[str, np.ndarray] | np.ndarray, actions: np.ndarray) -> None:
        """Hold the demonstrated (observations, actions) as tensors for ``demo_batch``, with its generator."""
        self._demo_observations = _tensors(observations, self.device)
        self._demo_actions = torch.as_tensor(actions, device=self.device)
        self._demo_generator = torch.Generator(device="cpu").manual_seed(0 if self.seed is None else int(self.seed))

    def _excluded_save_params(self) -> list[str]:
        return [*super()._excluded_save_params(), "_demo_observations", "_demo_actions", "_demo_generator"]

    @property
    def demonstration_steps(self) -> int:
        """How many demonstrated steps (observation, action) the model learns from."""
        return int(self._demo_actions.shape[0])

    def demo_batch(self, size: int) -> tuple[Any, torch.Tensor]:
        """``size`` demonstrated (observations, actions), drawn uniformly with replacement."""
        return self.demo_rows(self.demo_index(size))

    def demo_index(self, size: int) -> torch.Tensor:
        """``size`` indices of demonstrated steps, drawn uniformly with replacement."""
        return torch.randint(0, self.demonstration_steps, (size,), generator=self._demo_generator)

    def demo_rows(self, index: torch.Tensor) -> tuple[Any, torch.Tensor]:
        """The demonstrated (observations, actions) at ``index``."""
        index = index.to(self.device)
        return _rows(self._demo_observations, index), self._demo_actions[index]


def check_demonstrations(value: Any, algorithm: str) -> None:
    """``ValueError`` naming ``algorithm`` without ``algo_kwargs.demonstrations``, or with a bad spec of them."""
    if value is None:
        raise ValueError(f"{algorithm} needs algo_kwargs.demonstrations ({{dataset, episodes}})")
    Demonstrations.of(value)


class BufferedDemonstrationMixin(DemonstrationMixin, ABC):
    """Demonstrations that also start in the replay buffer: the episodes read at setup wait in
    ``_episodes_for_buffer`` (never saved) until the first ``learn`` of a fresh buffer puts them in with
    ``_fill_buffer``; a resumed run's buffer already holds them."""

    _episodes_for_buffer: list[Any] | None = None

    def _excluded_save_params(self) -> list[str]:
        return [*super()._excluded_save_params(), "_episodes_for_buffer"]

    def _setup_learn(self, total_timesteps: int, *args: Any, **kwargs: Any) -> Any:
        fresh = self.replay_buffer is not None and self.replay_buffer.size() == 0
        result = super()._setup_learn(total_timesteps, *args, **kwargs)
        if fresh and self._episodes_for_buffer:
            self._fill_buffer(self._episodes_for_buffer)
        self._episodes_for_buffer = None
        return result

    @abstractmethod
    def _fill_buffer(self, episodes: list[Any]) -> None:
        """Put the demonstrated ``episodes`` into the (empty) replay buffer."""


class BehaviourCloning(DemonstrationMixin, SAC):
    """Behaviour cloning into a SAC policy (actor and critics; only the actor learns): each step draws
    ``batch_size`` demonstrated steps and regresses the actor's deterministic action (tanh of its mean, what
    ``predict(deterministic=True)`` returns) onto the demonstrated actions (mean squared error).
    ``observation_noise``: the standard deviation of Gaussian noise added to every vector observation entry
    in training (metres for positions), so that the policy also sees states a little off the demonstrations.
    ``image_shift``: image observations are shifted by up to this many pixels each way, per sample (padding
    by repeating the border, then a random crop: the augmentation of DrQ, Kostrikov et al. 2020).
    ``num_timesteps`` counts minibatches; no env step is taken to learn."""

    def __init__(
        self,
        policy: Any,
        env: Any,
        demonstrations: dict[str, Any] | None = None,
        learning_rate: float | Any = 1e-3,
        batch_size: int = 256,
        observation_noise: float = 0.0,
        image_shift: int = 0,
        policy_kwargs: dict[str, Any] | None = None,
        tensorboard_log: str | None = None,
        verbose: int = 0,
        seed: int | None = None,
        device: str = "auto",
        _init_setup_model: bool = True,
    ) -> None:
        if _init_setup_model:
            check_demonstrations(demonstrations, "bc")
        if not (is_count(batch_size) and batch_size >= 1):
            raise ValueError(f"bc: batch_size must be an int >= 1, got {batch_size!r}")
        if not (is_number(observation_noise) and observation_noise >= 0):
            raise ValueError(f"bc: observation_noise must be a number >= 0, got {observation_noise!r}")
        if not (isinstance(image_shift, int) and not isinstance(image_shift, bool) and image_shift >= 0):
            raise ValueError(f"bc: image_shift must be an int >= 0 (pixels), got {image_shift!r}")
        self.demonstrations, self.observation_noise = demonstrations, float(observation_noise)
        self.image_shift = image_shift
        super().__init__(
            policy,
            env,
            learning_rate=learning_rate,
            buffer_size=1,
            learning_starts=0,
            batch_size=batch_size,
            policy_kwargs=policy_kwargs,
            tensorboard_log=tensorboard_log,
            verbose=verbose,
            seed=seed,
            device=device,
            _init_setup_model=_init_setup_model,
        )

    def _setup_model(self) -> None:
        super()._setup_model()
        self._setup_demonstrations()

    def learn(
        self,
        total_timesteps: int,
        callback: Any = None,
        log_interval: int = 100,
        tb_log_name: str = "BC",
        reset_num_timesteps: bool = True,
        progress_bar: bool = False,
    ) -> BehaviourCloning:
        total, callback = self._setup_learn(total_timesteps, callback, reset_num_timesteps, tb_log_name, progress_bar)
        callback.on_training_start(locals(), globals())
        self.policy.set_training_mode(True)
        while self.num_timesteps < total:
            self._update_current_progress_remaining(self.num_timesteps, total)
            self._update_learning_rate([self.actor.optimizer])
            observations, actions = self.demo_batch(self.batch_size)
            if self.observation_noise:
                observations = _noisy(observations, self.observation_noise, self._demo_generator)
            if self.image_shift:
                observations = _shifted(observations, self.image_shift, self._demo_generator)
            loss = functional.mse_loss(self.actor(observations, deterministic=True), actions)
            self.actor.optimizer.zero_grad()
            loss.backward()
            self.actor.optimizer.step()
            self.num_timesteps += 1
            self._n_updates += 1
            if self.num_timesteps % log_interval == 0:
                self.logger.record("train/bc_loss", loss.item())
                self.logger.dump(self.num_timesteps)
            if not callback.on_step():
                break
        self.policy.set_training_mode(False)
        callback.on_training_end()
        return self


class TQCFromDemonstrations(BufferedDemonstrationMixin, TQC):
    """TQC whose replay buffer starts with the demonstrations (HER relabels them like any episode) and whose
    actor, after each round of TQC updates, takes one behaviour-cloning step on ``batch_size`` demonstrated
    steps, weighted by ``bc_weight`` and kept only where the critics rate the demonstrated action above the
    policy's (the Q-filter).  The demonstrations enter the buffer ``n_envs`` episodes at a time, so their
    episodes must all have the same length (the low-level ids truncate at a fixed step count)."""

    def __init__(
        self, policy: Any, env: Any, demonstrations: dict[str, Any] | None = None, bc_weight: float = 1.0, **kwargs: Any
    ) -> None:
        if kwargs.get("_init_setup_model", True):
            check_demonstrations(demonstrations, "tqc_demos")
        if not (is_number(bc_weight) and bc_weight >= 0):
            raise ValueError(f"tqc_demos: bc_weight must be a number >= 0, got {bc_weight!r}")
        self.demonstrations, self.bc_weight = demonstrations, float(bc_weight)
        super().__init__(policy, env, **kwargs)

    def _setup_model(self) -> None:
        super()._setup_model()
        self._episodes_for_buffer = self._setup_demonstrations()

    def _fill_buffer(self, episodes: list[Any]) -> None:
        lengths = {len(e.actions) for e in episodes}
        n = self.n_envs
        if len(lengths) != 1:
            raise ValueError(
                f"tqc_demos: the demonstrations must be episodes of one length; got lengths {sorted(lengths)}"
            )
        length = lengths.pop()
        for first in range(0, len(episodes), n):
            # The buffer takes one episode per env at a time: a last, partial group (10 demonstrations on 4
            # envs) is completed with its own episodes again, so a few demonstrations enter it twice.
            group = episodes[first : first + n]
            group = [group[k % len(group)] for k in range(n)]
            for t in range(length):
                last = t == length - 1
                self.replay_buffer.add(
                    _stacked(group, t, self.observation_space),
                    _stacked(group, t + 1, self.observation_space),
                    np.stack([np.clip(e.actions[t], -1, 1) for e in group]),
                    np.array([e.rewards[t] for e in group], dtype=np.float32),
                    np.full(n, last),
                    [{"TimeLimit.truncated": last} for _ in group],
                )

    def train(self, gradient_steps: int, batch_size: int = 64) -> None:
        super().train(gradient_steps, batch_size)
        if self.bc_weight == 0:
            return
        observations, actions = self.demo_batch(self.batch_size)
        with torch.no_grad():  # the Q-filter: imitate only where the demonstration looks better to the critics
            policy_actions, _ = self.actor.action_log_prob(observations)
            demo_value = self.critic(observations, actions).mean(dim=(1, 2))
            policy_value = self.critic(observations, policy_actions).mean(dim=(1, 2))
            keep = (demo_value > policy_value).float()
        error = ((self.actor(observations, deterministic=True) - actions) ** 2).sum(dim=1)
        loss = self.bc_weight * (keep * error).sum() / keep.sum().clamp(min=1.0)
        self.actor.optimizer.zero_grad()
        loss.backward()
        self.actor.optimizer.step()
        self.logger.record("train/bc_loss", loss.item())
        self.logger.record("train/bc_q_filter", float(keep.mean()))  # the share that passed the filter
