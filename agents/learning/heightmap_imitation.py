"""Deep Q-learning from demonstrations (DQfD) for the ``pixel`` mode's heightmap Q-network: ``heightmap_dqn_demos``.

``HeightmapDQNFromDemonstrations`` reads ``algo_kwargs.demonstrations`` as the other learners from
demonstrations do (``imitation.Demonstrations``).  Distances are metres on the table, turns radians.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any

import numpy as np
import torch
from stable_baselines3.common.utils import polyak_update

from panda_grasp_env.agents.learning.acting_rules import DIRECTED_PRIMITIVES
from panda_grasp_env.agents.learning.heightmap_observations import encode_heightmap
from panda_grasp_env.agents.learning.heightmap_policy import HeightmapDQN, HeightmapQNetwork
from panda_grasp_env.agents.learning.imitation import (
    BufferedDemonstrationMixin,
    DemonstrationMixin,
    Demonstrations,
    check_demonstrations,
)
from panda_grasp_env.geometry import is_number

#: Cells this close to the demonstrated one (metres, Euclidean on the table), with the same primitive and
#: heading, count as the demonstrated action itself: the Q-maps are scored at a quarter of the heightmap's
#: resolution and upsampled, so no margin can part neighbouring cells, and the demonstrated action is worth the
#: best of them.
SAME_ACTION_RADIUS = 0.012
#: The margin grows linearly from nothing at ``SAME_ACTION_RADIUS`` to the whole ``margin`` at this distance
#: (metres): a cell 2 cm away is nearly the same grasp, and a Q-map smooth at 16 mm cannot rank it far below.
FULL_MARGIN_DISTANCE = 0.04
#: Likewise over headings (radians): the whole margin from this turn on, half of it at 22.5 degrees.
FULL_MARGIN_TURN = np.pi / 4


#: The supervised losses on demonstrations a ``LargeMarginMixin`` learner may take (``imitation_loss``).
IMITATION_LOSSES = ("margin", "cross_entropy")


class LargeMarginMixin(DemonstrationMixin):
    """DQfD's supervised loss for a ``HeightmapDQN``: after each round of TD updates, one supervised step
    (weighted by ``margin_weight``) on ``batch_size`` demonstrated steps (``DemonstrationMixin.demo_batch``),
    and ``_pretrain``: ``pretrain_steps`` such updates on the buffer alone, the target network following every
    ``target_update_interval`` of them, as it does env steps.  The step is DQfD's large margin
    (``imitation_loss="margin"``, ``large_margin_loss``) or behaviour cloning on the Q-maps
    (``"cross_entropy"``, ``demonstration_cross_entropy`` at ``temperature``)."""

    margin: float
    margin_weight: float
    pretrain_steps: int
    imitation_loss: str = "margin"
    temperature: float = 0.05
    #: Pretraining steps taken so far (saved with the model: a run stopped while pretraining goes on with it).
    pretrained_steps: int = 0
    #: Per demonstrated step, the headings after which its action is the same again (``large_margin_loss``'s
    #: ``periods``); None: a half turn, or a whole one for ``DIRECTED_PRIMITIVES``.
    _demo_periods: torch.Tensor | None = None

    def _set_margin(
        self,
        algorithm: str,
        margin: Any,
        margin_weight: Any,
        pretrain_steps: Any,
        imitation_loss: Any = "margin",
        temperature: Any = 0.05,
    ) -> None:
        """Check and keep the supervised loss's settings; ``ValueError`` naming ``algorithm`` and the bad one."""
        for name, value in (("margin", margin), ("margin_weight", margin_weight)):
            if not (is_number(value) and value >= 0):
                raise ValueError(f"{algorithm}: {name} must be a number >= 0, got {value!r}")
        if not (isinstance(pretrain_steps, int) and not isinstance(pretrain_steps, bool) and pretrain_steps >= 0):
            raise ValueError(f"{algorithm}: pretrain_steps must be an int >= 0, got {pretrain_steps!r}")
        if imitation_loss not in IMITATION_LOSSES:
            raise ValueError(f"{algorithm}: imitation_loss must be one of {IMITATION_LOSSES}, got {imitation_loss!r}")
        if not (is_number(temperature) and temperature > 0):
            raise ValueError(f"{algorithm}: temperature must be a number > 0, got {temperature!r}")
        self.margin, self.margin_weight, self.pretrain_steps = float(margin), float(margin_weight), pretrain_steps
        self.imitation_loss, self.temperature = imitation_loss, float(temperature)
        self.pretrained_steps = 0

    def _excluded_save_params(self) -> list[str]:
        return [*super()._excluded_save_params(), "_demo_periods"]

    def _pretrain(self) -> None:
        while self.pretrained_steps < self.pretrain_steps:
            self._update(1, self.batch_size)
            self.pretrained_steps += 1
            if self.pretrained_steps % self.target_update_interval == 0 or self.pretrained_steps == self.pretrain_steps:
                polyak_update(self.q_net.parameters(), self.q_net_target.parameters(), 1.0)

    def train(self, gradient_steps: int, batch_size: int = 100) -> None:
        self._update(gradient_steps, batch_size)

    def _update(self, gradient_steps: int, batch_size: int) -> None:
        """``gradient_steps`` TD updates, then one supervised step."""
        super().train(gradient_steps, batch_size)
        if self.margin_weight == 0:
            return
        loss, met = self.supervised_loss(*self.margin_batch(batch_size))
        self.policy.optimizer.zero_grad()
        loss.backward()
        torch.nn.utils.clip_grad_norm_(self.policy.parameters(), self.max_grad_norm)
        self.policy.optimizer.step()
        name = "margin" if self.imitation_loss == "margin" else "imitation"
        self.logger.record(f"train/{name}_loss", loss.item())
        self.logger.record(f"train/{name}_met", met)

    def margin_batch(self, size: int) -> tuple[Any, torch.Tensor, torch.Tensor | None]:
        """``size`` demonstrated (observations, actions, periods or None), drawn uniformly with replacement."""
        index = self.demo_index(size)
        return *self.demo_rows(index), None if self._demo_periods is None else self._demo_periods[index]

    def margin_loss(
        self, observations: torch.Tensor, actions: torch.Tensor, periods: torch.Tensor | None = None
    ) -> tuple[torch.Tensor, float]:
        """(the weighted ``large_margin_loss`` of demonstrated ``actions`` (B,) on encoded heightmaps
        ``observations``, the share of them that already beat every other allowed action by the margin)."""
        cell = self.policy.network_args["cell_size"]
        loss, met = large_margin_loss(
            self.q_net, observations, actions, self.margin, cell, self._demo_generator, periods
        )
        return self.margin_weight * loss, met

    def supervised_loss(
        self, observations: torch.Tensor, actions: torch.Tensor, periods: torch.Tensor | None = None
    ) -> tuple[torch.Tensor, float]:
        """The ``imitation_loss`` of demonstrated ``actions`` (B,) on encoded heightmaps ``observations``,
        weighted by ``margin_weight``, and the share of them that the Q-maps already rank first (by the margin,
        for ``"margin"``)."""
        if self.imitation_loss == "margin":
            return self.margin_loss(observations, actions, periods)
        cell = self.policy.network_args["cell_size"]
        loss, met = demonstration_cross_entropy(
            self.q_net, observations, actions, self.temperature, cell, self._demo_generator, periods
        )
        return self.margin_weight * loss, met


class HeightmapDQNFromDemonstrations(BufferedDemonstrationMixin, LargeMarginMixin, HeightmapDQN):
    """``HeightmapDQN`` with demonstrations (DQfD, Hester et al. 2018, "Deep Q-learning from demonstrations"):
    the demonstrated transitions start in the replay buffer, where they stay (a ``buffer_size`` below them and
    the run's steps is refused), and after each round of TD updates the Q-network takes one large-margin step
    on ``batch_size`` demonstrated steps, ``margin_weight * mean(max_a [Q(s, a) + l(a_E, a)] - Q(s, a_E))``
    (DQfD's supervised loss).  The margin ``l`` is graded, as the actions are alike: ``margin`` against
    another primitive; for the same primitive, ``margin`` times the larger of how far (0 within
    ``SAME_ACTION_RADIUS``, rising to 1 at ``FULL_MARGIN_DISTANCE``) and how much turned (rising to 1 at
    ``FULL_MARGIN_TURN``) it is from a_E, whose value is that of the best cell within ``SAME_ACTION_RADIUS``.
    A flat margin against neighbouring cells and headings, which the Q-maps cannot part, is never met and
    only flattens them.  The maximum runs over the demonstrated
    heading's map and one other heading drawn at random (two network passes per sample, not all
    ``rotations``; never the half-turned grasp, which is the same grasp), so over the run every heading
    is held below the demonstrated action.  With ``pretrain_steps``, that many such updates on the
    demonstrations alone come before the first env step (DQfD's pretraining).

    The demonstrations are episodes in ``obs_mode='heightmap'`` and ``action_mode='pixel'``, e.g. the
    push-aware oracle's (``python -m panda_grasp_env.agents.learning.demonstrations --agent oracle --task
    GraspAdversarial --task-options obs_mode=heightmap action_mode=pixel ...``), with the rewards they were
    recorded under; policies with the holding or command planes cannot learn from them (their episodes do
    not say what was held or commanded)."""

    def __init__(
        self,
        policy: Any,
        env: Any,
        demonstrations: dict[str, Any] | None = None,
        margin: float = 0.2,
        margin_weight: float = 1.0,
        pretrain_steps: int = 0,
        imitation_loss: str = "margin",
        temperature: float = 0.05,
        **kwargs: Any,
    ) -> None:
        if kwargs.get("_init_setup_model", True):
            check_demonstrations(demonstrations, "heightmap_dqn_demos")
        self._set_margin("heightmap_dqn_demos", margin, margin_weight, pretrain_steps, imitation_loss, temperature)
        self.demonstrations = demonstrations
        super().__init__(policy, env, **kwargs)

    def _setup_model(self) -> None:
        super()._setup_model()
        if self.n_envs != 1:
            raise ValueError(
                f"heightmap_dqn_demos: n_envs must be 1 (the demonstrations enter the buffer one "
                f"step at a time), got {self.n_envs}"
            )
        spec = Demonstrations.of(self.demonstrations)
        planes, rows, cols = self.observation_space.shape
        if planes != 4:
            raise ValueError(
                f"heightmap_dqn_demos: the policy sees {planes} planes; demonstrations give the "
                f"heightmap's 4 (no holding or command planes)"
            )
        episodes = []
        for episode in spec.episodes_data():
            heightmaps = np.asarray(episode.observations)
            if heightmaps.shape[1:] != (rows, cols, 4):
                raise ValueError(
                    f"demonstrations {spec.dataset}: observations of shape {heightmaps.shape[1:]}, "
                    f"the env's heightmap ({rows}, {cols}, 4) (obs_mode='heightmap')"
                )
            actions = np.asarray(episode.actions).reshape(-1)
            if actions.dtype.kind not in "iu" or actions.min() < 0 or actions.max() >= self.action_space.n:
                raise ValueError(
                    f"demonstrations {spec.dataset}: actions are not indices of this env's "
                    f"{self.action_space} (action_mode='pixel' with the same grid and rotations)"
                )
            encoded = np.stack([encode_heightmap(h) for h in heightmaps])
            episodes.append((encoded, actions.astype(np.int64), episode))
        self._keep_demonstrations(
            np.concatenate([e[0][:-1] for e in episodes]), np.concatenate([e[1] for e in episodes])
        )
        self._episodes_for_buffer = episodes

    def _setup_learn(self, total_timesteps: int, *args: Any, **kwargs: Any) -> Any:
        result = super()._setup_learn(total_timesteps, *args, **kwargs)
        steps = result[0]  # the run's whole length, a resumed run's steps so far included
        if self.buffer_size < self.demonstration_steps + steps:
            raise ValueError(
                f"heightmap_dqn_demos: buffer_size {self.buffer_size} cannot keep the "
                f"{self.demonstration_steps} demonstrated steps and the run's {steps}"
            )
        self._pretrain()
        return result

    def _fill_buffer(self, episodes: list[Any]) -> None:
        for encoded, actions, episode in episodes:
            for t, action in enumerate(actions):
                terminated, truncated = bool(episode.terminations[t]), bool(episode.truncations[t])
                self.replay_buffer.add(
                    encoded[t][None],
                    encoded[t + 1][None],
                    np.array([[action]]),
                    np.array([episode.rewards[t]], dtype=np.float32),
                    np.array([terminated or truncated]),
                    [{"TimeLimit.truncated": truncated and not terminated}],
                )


@dataclass(frozen=True)
class _Demonstrated:
    """Demonstrated actions (B,) unpacked against a Q-network's maps, as both supervised losses read them."""

    primitive: torch.Tensor
    rotation: torch.Tensor
    #: (B, P, H, W) bool: the actions worth considering (alike at every heading), a_E's own cell always among them
    allowed: torch.Tensor
    #: (B, H, W) bool: the allowed cells of a_E's primitive within ``SAME_ACTION_RADIUS`` of a_E's cell
    same_action: torch.Tensor
    #: (B, H, W) how far past ``SAME_ACTION_RADIUS`` each cell lies, as a share of the margin's ramp (0 to 1)
    apart: torch.Tensor
    #: (B,) the rotation index of the other map each loss reads (never one after which a_E repeats), and
    #: whether one exists
    other_rotation: torch.Tensor
    has_other: torch.Tensor
    #: (B,) that turn in ``FULL_MARGIN_TURN``s, up to the nearest heading after which a_E repeats
    turned: torch.Tensor


def _demonstrated(
    q_net: HeightmapQNetwork,
    observations: torch.Tensor,
    actions: torch.Tensor,
    cell_size: float,
    generator: torch.Generator,
    periods: torch.Tensor | None,
) -> _Demonstrated:
    """Unpack ``actions`` (B,) on ``observations`` and draw, per action, one other heading that is never the same
    action (a multiple of ``periods`` away; default a half turn, or a whole one for ``DIRECTED_PRIMITIVES``)."""
    rotations, rows, cols = q_net.rotations, q_net.rows, q_net.cols
    shape = (q_net.n_primitives, rotations, rows, cols)
    primitive, rotation, row, col = (torch.as_tensor(i) for i in np.unravel_index(actions.cpu().numpy(), shape))
    index = torch.arange(len(actions))
    allowed = q_net.allowed(observations).view(len(actions), *shape)[:, :, 0]  # alike at every heading
    allowed[index, primitive, row, col] = True
    distance = cell_size * torch.hypot(
        (torch.arange(rows)[None, :, None] - row[:, None, None]).float(),
        (torch.arange(cols)[None, None, :] - col[:, None, None]).float(),
    )
    same_action = (distance <= SAME_ACTION_RADIUS) & allowed[index, primitive]
    apart = ((distance - SAME_ACTION_RADIUS) / (FULL_MARGIN_DISTANCE - SAME_ACTION_RADIUS)).clamp(0.0, 1.0)
    if periods is None:
        periods = torch.tensor(
            [
                rotations // 2 if rotations % 2 == 0 and q_net.primitives[p] not in DIRECTED_PRIMITIVES else rotations
                for p in primitive.tolist()
            ]
        )
    choices = rotations - rotations // periods
    # Drawn only where some action has another heading, so that the generator's stream is the margin's as before.
    drawn = (torch.rand(len(actions), generator=generator) * choices).long() if bool((choices > 0).any()) else choices
    turn = drawn + 1 + drawn // (periods - 1).clamp(min=1)  # skips the multiples of the period
    steps = turn % periods
    turned = torch.minimum(steps, periods - steps) * (2 * np.pi / rotations) / FULL_MARGIN_TURN
    return _Demonstrated(
        primitive, rotation, allowed, same_action, apart, (rotation + turn) % rotations, choices > 0, turned
    )


def large_margin_loss(
    q_net: HeightmapQNetwork,
    observations: torch.Tensor,
    actions: torch.Tensor,
    margin: float,
    cell_size: float,
    generator: torch.Generator,
    periods: torch.Tensor | None = None,
) -> tuple[torch.Tensor, float]:
    """DQfD's large-margin loss of demonstrated ``actions`` (B,) on encoded heightmaps ``observations``,
    ``mean(max_a [Q(s, a) + l(a_E, a)] - Q(s, a_E))``, graded as ``HeightmapDQNFromDemonstrations`` says (cells
    ``cell_size`` metres apart) over the demonstrated heading's map and one other drawn from ``generator``, with
    ``Q(s, a_E)`` the best allowed cell within ``SAME_ACTION_RADIUS`` of a_E on its map; and the share of the
    demonstrated actions that already beat every other allowed action by the margin at the headings tried.
    ``periods`` (B,): the headings after which each demonstrated action is the same again (default: a half
    turn, or a whole one for ``DIRECTED_PRIMITIVES``); the other heading is never one of those."""
    shown = _demonstrated(q_net, observations, actions, cell_size, generator, periods)
    index = torch.arange(len(actions))

    def best_allowed(scores: torch.Tensor) -> torch.Tensor:
        return scores.masked_fill(~shown.allowed, -torch.inf).flatten(1).amax(1)

    demonstrated = q_net.q_maps(observations, shown.rotation)
    # a_E's value is the best of its own disk: the upsampled maps peak where they will, and an argmax anywhere
    # in the disk takes the demonstrated action.
    chosen = demonstrated[index, shown.primitive].masked_fill(~shown.same_action, -torch.inf).flatten(1).amax(1)

    def margins(turned: torch.Tensor) -> torch.Tensor:
        """(B, P, H, W) margins on a map turned by ``turned`` (B,) of ``FULL_MARGIN_TURN``s from a_E's."""
        graded = torch.full_like(demonstrated, margin)
        graded[index, shown.primitive] = margin * torch.maximum(shown.apart, turned.clamp(max=1.0)[:, None, None])
        return graded

    best = best_allowed(demonstrated + margins(torch.zeros(len(actions))))
    if bool(shown.has_other.any()):
        elsewhere = best_allowed(q_net.q_maps(observations, shown.other_rotation) + margins(shown.turned))
        best = torch.where(shown.has_other, torch.maximum(best, elsewhere), best)
    return (best - chosen).mean(), float((best - chosen <= 1e-6).float().mean())


def demonstration_cross_entropy(
    q_net: HeightmapQNetwork,
    observations: torch.Tensor,
    actions: torch.Tensor,
    temperature: float,
    cell_size: float,
    generator: torch.Generator,
    periods: torch.Tensor | None = None,
) -> tuple[torch.Tensor, float]:
    """Behaviour cloning on the Q-maps: ``-log`` of the probability that ``softmax(Q / temperature)`` over every
    allowed action of the demonstrated heading's map and one other heading's (drawn as ``large_margin_loss``
    draws it) gives to a_E's disk (the allowed cells within ``SAME_ACTION_RADIUS`` of it, on its map), averaged
    over the batch; and the share of the demonstrated actions whose disk already holds the best of those
    actions.  Unlike the margin, which moves only a_E's best cell and the single best rival, every allowed
    cell gets a gradient, in proportion to the probability it takes from a_E."""
    shown = _demonstrated(q_net, observations, actions, cell_size, generator, periods)
    index = torch.arange(len(actions))
    demonstrated = q_net.q_maps(observations, shown.rotation).masked_fill(~shown.allowed, -torch.inf)
    disk = torch.zeros_like(shown.allowed)
    disk[index, shown.primitive] = shown.same_action
    logits = [demonstrated.flatten(1) / temperature]
    if bool(shown.has_other.any()):
        elsewhere = q_net.q_maps(observations, shown.other_rotation).masked_fill(~shown.allowed, -torch.inf)
        elsewhere = elsewhere.masked_fill(~shown.has_other[:, None, None, None], -torch.inf)
        logits.append(elsewhere.flatten(1) / temperature)
    every = torch.cat(logits, 1)
    in_disk = logits[0].masked_fill(~disk.flatten(1), -torch.inf)
    loss = (torch.logsumexp(every, 1) - torch.logsumexp(in_disk, 1)).mean()
    met = (in_disk.amax(1) >= every.amax(1)).float().mean()
    return loss, float(met)
