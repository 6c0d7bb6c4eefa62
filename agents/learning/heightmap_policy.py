"""A VPG-style heightmap Q-network for the ``pixel`` action mode, as an SB3 DQN policy.

The ``pixel`` action index is ((primitive * R + rotation) * H + row) * W + column.
For every rotation r (heading 2 pi r / R) the heightmap is rotated so the
heading points along the image's +column axis, one small fully convolutional
network scores every cell for every primitive at quarter resolution, and the
scores are upsampled and rotated back (Zeng et al. 2018).  So one set of
weights serves all headings and the Q-map moves with the objects.

Actions are masked from the observation itself: grasps only on occupied cells
(height above ``PixelActions.OCCUPIED``), pushes only near them (a square of
``PixelActions.NEAR``), primitives not in ``primitives_used`` never -- for
acting, exploring and the TD target.  A policy that uses ``place`` sees a
fifth plane, whether the hand holds something (``holding_after``): places only
on occupied cells and only when holding, grasps and pushes only with an empty
hand (SPOT's masking for stacking).  Without it the policy assumes an empty
hand (true for ``Grasp``, which sets the grasped object aside).  A task with a
commanded heading (the directional TowerBreak) adds two planes, the command's
cos and sin; for each rotation the network sees them as the command's
direction *relative to that rotation's heading* (two constant planes after the
map is rotated), so one set of weights learns "push where the command points"
for every heading.
A goal-conditioned structure task adds the goal plane (the goal heightmap,
``encode_heightmap``'s ``goal``) after the holding plane: the network sees it
rotated with the map, and beside it what the goal still lacks (the goal's
height above the table's, cell by cell), and places are allowed on the goal's
footprint as well as on occupied cells.  Its heights span ``GOAL_HEIGHT_RANGE``
(2 mm a level) instead of ``HEIGHT_RANGE``: tall towers are goals too.

``HeightmapDQN`` trains only the rotation that was taken (one network pass per
sample instead of R), as VPG does.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from typing import Any

import gymnasium as gym
import numpy as np
import torch as th
import torch.nn.functional as F
from stable_baselines3 import DQN
from stable_baselines3.dqn.policies import DQNPolicy
from torch import nn

from panda_grasp_env.actions import PixelActions
from panda_grasp_env.agents.learning.acting_rules import FaceCentring, FailureMemory, InwardPushes, LackingPlaces
from panda_grasp_env.agents.learning.heightmap_observations import GOAL_HEIGHT_RANGE, HEIGHT_RANGE
from panda_grasp_env.perception.heightmap import HeightmapGrid


def rotation_matrices(angles: th.Tensor) -> th.Tensor:
    """(N, 2, 3) ``affine_grid`` matrices sampling the input at ``angles`` (radians, image x/y) from each output point."""
    cos, sin = th.cos(angles), th.sin(angles)
    zero = th.zeros_like(angles)
    return th.stack([th.stack([cos, -sin, zero], -1), th.stack([sin, cos, zero], -1)], -2)


def heading_in_image(yaw: th.Tensor) -> th.Tensor:
    """Angle (image x = column, y = row) of the world heading ``yaw``: rows run along -x, columns along -y."""
    return th.atan2(-th.cos(yaw), -th.sin(yaw))


def rotation_grid(angles: th.Tensor, side: int) -> th.Tensor:
    """(N, S, S, 2) ``grid_sample`` grid that rotates square images (N, C, S, S) so that image direction
    ``angles`` (N,) ends up along +x."""
    return F.affine_grid(rotation_matrices(angles), [len(angles), 1, side, side], align_corners=False)


def sample(images: th.Tensor, grid: th.Tensor) -> th.Tensor:
    """``images`` (N, C, S, S) bilinearly sampled at ``grid`` (N, H, W, 2) (zeros outside)."""
    return F.grid_sample(images, grid, mode="bilinear", padding_mode="zeros", align_corners=False)


class HeightmapQNetwork(nn.Module):
    """Q-values of every ``pixel`` action from an encoded heightmap (B, 4-8, H, W) uint8."""

    def __init__(
        self,
        shape: tuple[int, int, int, int],
        primitives: tuple[str, ...],
        used: tuple[str, ...],
        width: int,
        near_cells: int,
        holding: bool = False,
        command: bool = False,
        refine: bool = False,
        goal: bool = False,
    ) -> None:
        """``shape``: (primitives, rotations, rows, cols); ``near_cells``: push-mask radius in cells;
        ``holding``: the input has the holding plane (after the heightmap's 4); ``goal``: then the goal plane;
        ``command``: it ends with the two command planes; ``refine``: add a half-resolution correction of the
        quarter-resolution scores (see ``_scores``)."""
        super().__init__()
        self.holding, self.command, self.goal = holding, command, goal
        self.goal_plane = 4 + int(holding)
        channels = 4 + int(holding) + 2 * int(goal) + 2 * int(command)
        self.n_primitives, self.rotations, self.rows, self.cols = shape
        self.primitives, self.used = primitives, used
        side = math.ceil(math.hypot(self.rows, self.cols) / 4) * 4  # rotations never cut the workspace off
        self.side = side
        self.pad = (
            (side - self.cols) // 2,
            side - self.cols - (side - self.cols) // 2,
            (side - self.rows) // 2,
            side - self.rows - (side - self.rows) // 2,
        )
        self.net = nn.Sequential(
            nn.Conv2d(channels, 16, 5, stride=2, padding=2),
            nn.ReLU(inplace=True),
            nn.Conv2d(16, 32, 3, stride=2, padding=1),
            nn.ReLU(inplace=True),
            nn.Conv2d(32, width, 3, padding=1),
            nn.ReLU(inplace=True),
            nn.Conv2d(width, width, 3, padding=2, dilation=2),
            nn.ReLU(inplace=True),
            nn.Conv2d(width, width, 3, padding=1),
            nn.ReLU(inplace=True),
            nn.Conv2d(width, self.n_primitives, 1),
        )
        # Quarter-resolution scores peak only on a 4-cell grid (16 mm at 4 mm cells), too coarse to centre a
        # block on a tower (10 mm tolerance); the refinement adds detail from the first (half-resolution)
        # features.  Its last layer starts at zero, so a refined network starts as the plain one.
        self.refine = None
        if refine:
            self.refine = nn.Sequential(
                nn.Conv2d(16 + width, 32, 3, padding=1), nn.ReLU(inplace=True), nn.Conv2d(32, self.n_primitives, 1)
            )
            nn.init.zeros_(self.refine[-1].weight)
            nn.init.zeros_(self.refine[-1].bias)
        headings = 2 * math.pi * th.arange(self.rotations) / self.rotations
        self.register_buffer("angles", heading_in_image(headings), persistent=False)
        # forward() always runs the same headings: their sampling grids are made once.
        self.register_buffer("grids_in", rotation_grid(self.angles, side), persistent=False)
        self.register_buffer("grids_back", self._crop(rotation_grid(-self.angles, side)).contiguous(), persistent=False)
        self.near_cells = near_cells

    def _crop(self, images: th.Tensor) -> th.Tensor:
        """The workspace (rows, cols) out of padded (N, S, S, ...) maps or grids."""
        left, _, top, _ = self.pad
        return images[:, top : top + self.rows, left : left + self.cols]

    def _scores(
        self, heightmaps: th.Tensor, angles: th.Tensor, grids: tuple[th.Tensor, th.Tensor] | None = None
    ) -> th.Tensor:
        """(N, P, H, W) scores of encoded heightmaps (N, C, H, W) float 0-1, each at heading angle ``angles[n]``.

        ``grids``: the sampling grids of ``angles`` (into the rotated frame, and back onto the workspace)
        where they are known already.  Sampling back only the workspace's cells gives the same numbers as
        rotating the whole padded map back and cropping it."""
        maps = heightmaps[:, :-2] if self.command else heightmaps
        if self.goal:
            lacking = (maps[:, self.goal_plane : self.goal_plane + 1] - maps[:, 3:4]).clamp(min=0.0)
            maps = th.cat([maps, lacking], 1)
        if grids is None:
            grids = rotation_grid(angles, self.side), self._crop(rotation_grid(-angles, self.side))
        rotated = sample(F.pad(maps, self.pad), grids[0])
        if self.command:
            cos_sin = heightmaps[:, -2:, 0, 0] * (255.0 / 127.0) - 1.0
            relative = heading_in_image(th.atan2(cos_sin[:, 1], cos_sin[:, 0])) - angles
            planes = th.stack([th.cos(relative), th.sin(relative)], 1)[:, :, None, None]
            rotated = th.cat([rotated, planes.expand(-1, -1, self.side, self.side)], 1)
        half = self.net[:2](rotated)
        features = self.net[2:-1](half)
        coarse = self.net[-1](features)
        if self.refine is not None:
            up = F.interpolate(features, scale_factor=2.0, mode="bilinear", align_corners=False)
            coarse = F.interpolate(coarse, scale_factor=2.0, mode="bilinear", align_corners=False)
            coarse = coarse + self.refine(th.cat([half, up], 1))
        fine = F.interpolate(coarse, size=(self.side, self.side), mode="bilinear", align_corners=False)
        return sample(fine, grids[1])

    def forward(self, observations: th.Tensor) -> th.Tensor:
        """(B, P * R * H * W) Q-values, in the env's action order."""
        batch = observations.shape[0]
        images = observations.float().div(255.0)
        repeated = images.repeat_interleave(self.rotations, 0)
        grids = (self.grids_in, self.grids_back)
        if batch > 1:
            grids = (self.grids_in.repeat(batch, 1, 1, 1), self.grids_back.repeat(batch, 1, 1, 1))
        scores = self._scores(repeated, self.angles.repeat(batch), grids)  # (B * R, P, H, W)
        scores = scores.view(batch, self.rotations, self.n_primitives, self.rows, self.cols).transpose(1, 2)
        return scores.reshape(batch, -1)

    def set_training_mode(self, mode: bool) -> None:
        self.train(mode)

    def q_maps(self, observations: th.Tensor, rotations: th.Tensor) -> th.Tensor:
        """(B, P, H, W) Q-values of every primitive and cell at one rotation index (B,) per observation."""
        return self._scores(observations.float().div(255.0), self.angles[rotations])

    def q_at(self, observations: th.Tensor, actions: th.Tensor) -> th.Tensor:
        """Q-values (B,) of one action per observation, running only that action's rotation."""
        p, r, row, col = np.unravel_index(
            actions.cpu().numpy().reshape(-1), (self.n_primitives, self.rotations, self.rows, self.cols)
        )
        scores = self.q_maps(observations, th.as_tensor(r))
        index = th.arange(len(p))
        return scores[index, th.as_tensor(p), th.as_tensor(row), th.as_tensor(col)]

    def allowed(self, observations: th.Tensor) -> th.Tensor:
        """(B, P * R * H * W) bool: the actions worth considering on these heightmaps (see the module doc)."""
        scale = (GOAL_HEIGHT_RANGE if self.goal else HEIGHT_RANGE) / 255.0
        height = observations[:, 3:4].float() * scale
        occupied = height > PixelActions.OCCUPIED
        radius = self.near_cells
        # A square max filter, as a column pass then a row pass (the same maxima, far fewer comparisons).
        columns = F.max_pool2d(occupied.float(), (2 * radius + 1, 1), stride=1, padding=(radius, 0))
        near = F.max_pool2d(columns, (1, 2 * radius + 1), stride=1, padding=(0, radius)) > 0
        if self.holding:
            holding = observations[:, 4:5].amax((2, 3), keepdim=True) > 127
        else:
            holding = th.zeros_like(occupied[:, :, :1, :1])
        targets = occupied
        if self.goal:
            goal_height = observations[:, self.goal_plane : self.goal_plane + 1].float() * scale
            targets = occupied | (goal_height > PixelActions.OCCUPIED)
        by_name = {"grasp": occupied & ~holding, "place": targets & holding}
        per_primitive = th.cat([by_name.get(name, near & ~holding) for name in self.primitives], 1)
        used = th.tensor([name in self.used for name in self.primitives], device=observations.device)
        mask = per_primitive.unsqueeze(2) & used.view(1, -1, 1, 1, 1)
        mask = mask.expand(-1, -1, self.rotations, -1, -1).reshape(observations.shape[0], -1)
        empty = ~mask.any(1)  # nothing on the table: any used action rather than none
        if empty.any():
            everything = used.view(-1, 1).expand(-1, self.rotations * self.rows * self.cols).reshape(1, -1)
            mask = th.where(empty.view(-1, 1), everything, mask)
        return mask


class HeightmapQPolicy(DQNPolicy):
    """SB3 DQN policy around ``HeightmapQNetwork``; actions outside ``allowed`` are never chosen.

    Args (``policy_kwargs``):
        primitives: the env's primitives, in its order (``info``/task ``primitives``).
        rotations: headings in the env's ``pixel`` mode.
        cell_size: heightmap resolution, metres per cell.
        primitives_used: the primitives this policy may choose (default: all but ``place``; ``place`` needs
            the holding plane: ``EncodedHeightmap(env, holding_plane=True)``).
        width: channels of the network's inner layers.
        refine: score at half instead of quarter resolution (``HeightmapQNetwork``), for precise places.
        command: the observations end with the two command planes (``encode_heightmap``'s ``heading``).
        goal: the observations hold the goal plane after the holding plane (``encode_heightmap``'s ``goal``).
    """

    #: The name policy files give this class (``policy_files.class_name``): fixed, so that moving this module
    #: renames nothing in the files already written (shipped checkpoints, run folders).  It is the module the
    #: first checkpoints were saved from, not where the class lives now.
    policy_file_name = "panda_grasp_env.agents.heightmap_policy:HeightmapQPolicy"

    def __init__(
        self,
        observation_space: gym.spaces.Box,
        action_space: gym.spaces.Discrete,
        lr_schedule: Any,
        primitives: tuple[str, ...] = ("grasp", "push"),
        rotations: int = 16,
        cell_size: float = 0.004,
        primitives_used: tuple[str, ...] | None = None,
        width: int = 48,
        refine: bool = False,
        command: bool = False,
        goal: bool = False,
        optimizer_class: type[th.optim.Optimizer] = th.optim.Adam,
        optimizer_kwargs: dict[str, Any] | None = None,
    ) -> None:
        primitives = tuple(primitives)
        extra = 2 * int(command) + int(goal)
        planes = observation_space.shape[0] - extra if len(observation_space.shape) == 3 else 0
        if planes not in (4, 5):
            raise ValueError(
                f"HeightmapQPolicy needs encoded heightmaps ({4 + extra} or {5 + extra}, rows, cols), got "
                f"{observation_space}"
            )
        sees_hand = planes == 5
        used = tuple(p for p in primitives if p != "place") if primitives_used is None else tuple(primitives_used)
        unknown = [p for p in used if p not in primitives or (p == "place" and not sees_hand)]
        if unknown or not used:
            valid = [p for p in primitives if p != "place" or sees_hand]
            raise ValueError(
                f"primitives_used {list(used)}: each must be one of {valid}"
                + ("" if sees_hand else " (place needs the holding plane)")
            )
        shape = (len(primitives), int(rotations), *observation_space.shape[1:])
        if int(np.prod(shape)) != action_space.n:
            raise ValueError(f"action space {action_space} does not match {shape} (primitives x rotations x cells)")
        if not cell_size > 0:
            raise ValueError(f"cell_size must be a positive number of metres, got {cell_size!r}")
        self.network_args = {
            "primitives": primitives,
            "rotations": int(rotations),
            "cell_size": float(cell_size),
            "primitives_used": used,
            "width": int(width),
            "refine": bool(refine),
            "command": bool(command),
            "goal": bool(goal),
        }
        self.shape = shape
        super().__init__(
            observation_space,
            action_space,
            lr_schedule,
            normalize_images=False,
            optimizer_class=optimizer_class,
            optimizer_kwargs=optimizer_kwargs,
        )

    def make_q_net(self) -> HeightmapQNetwork:  # type: ignore[override]
        args = self.network_args
        near_cells = max(1, round(PixelActions.NEAR / args["cell_size"]))
        network = HeightmapQNetwork(
            self.shape,
            args["primitives"],
            args["primitives_used"],
            args["width"],
            near_cells,
            holding=self.observation_space.shape[0] - 2 * args["command"] - args["goal"] == 5,
            command=args["command"],
            refine=args["refine"],
            goal=args["goal"],
        )
        return network.to(self.device)

    def _predict(self, observation: th.Tensor, deterministic: bool = True) -> th.Tensor:
        return self._best_allowed(observation)

    def _best_allowed(self, observations: th.Tensor, excluded: th.Tensor | None = None) -> th.Tensor:
        """(B,) the best allowed actions, avoiding ``excluded`` (B, actions) where that leaves any."""
        allowed = self.q_net.allowed(observations)
        if excluded is not None:
            others = allowed & ~excluded
            allowed = th.where(others.any(1, keepdim=True), others, allowed)
        return self.q_net(observations).masked_fill(~allowed, -th.inf).argmax(dim=1)

    def greedy_action(self, observation: np.ndarray, excluded: np.ndarray | None = None) -> int:
        """The best allowed action on one encoded heightmap (C, H, W), avoiding ``excluded`` (bool per
        action, e.g. ``FailureMemory.excluded``) unless that leaves no allowed action."""
        with th.no_grad():
            batch = th.as_tensor(observation[None], device=self.device)
            avoid = None if excluded is None else th.as_tensor(excluded, device=self.device)[None]
            return int(self._best_allowed(batch, avoid))

    def failure_memory(self) -> FailureMemory:
        """An empty ``FailureMemory`` for this policy's actions (``PolicyAgent(avoid_failures=True)`` keeps one)."""
        height_range = GOAL_HEIGHT_RANGE if self.network_args["goal"] else HEIGHT_RANGE
        return FailureMemory(self.shape, self.network_args["cell_size"], self.network_args["primitives"], height_range)

    def face_centring(
        self, block_size: float, base: Sequence[float] | None = None, layout: dict[str, Any] | None = None
    ) -> FaceCentring:
        """A ``FaceCentring`` for this policy's actions on blocks of edge ``block_size`` metres, with the tower
        base's centre ``base`` (world metres) if known, placed on the grid of the env's action ``layout``
        (``info["action_layout"]``) (``PolicyAgent(centre_on_faces=True)`` keeps one)."""
        if self.network_args["goal"]:
            raise ValueError("face_centring centres on equal cube faces of a tower; a structure policy has planks too")
        if base is not None and layout is None:
            raise ValueError("face_centring: a base position needs the env's action layout to find its cell")
        cell = None if base is None else tuple(HeightmapGrid.of_layout(layout).cell_position(base[:2]).tolist())
        args = self.network_args
        return FaceCentring(self.shape, args["cell_size"], args["primitives"], block_size, cell)

    def inward_pushes(self) -> InwardPushes:
        """``InwardPushes`` for this policy's actions (``PolicyAgent(inward_pushes=True)`` keeps one)."""
        return InwardPushes(self.shape, self.network_args["cell_size"], self.network_args["primitives"])

    def lacking_places(self) -> LackingPlaces:
        """``LackingPlaces`` for this goal-conditioned policy's actions (``PolicyAgent(place_where_lacking=True)``
        keeps one)."""
        args = self.network_args
        if not args["goal"]:
            raise ValueError("lacking_places reads the goal heightmap; this policy sees none")
        return LackingPlaces(self.shape, args["cell_size"], args["primitives"], self.q_net.goal_plane)

    def on_grid(self, rows: int, cols: int) -> HeightmapQPolicy:
        """This policy's weights acting on a heightmap of ``rows`` x ``cols`` cells at the same resolution (a
        wider or narrower view): the network is fully convolutional, so only the action grid changes.  Itself
        if the grid is its own."""
        if (rows, cols) == tuple(self.shape[2:]):
            return self
        if rows < 4 or cols < 4:
            raise ValueError(f"a heightmap policy needs a grid of at least 4 x 4 cells, got {rows} x {cols}")
        space = self.observation_space
        observations = gym.spaces.Box(0, 255, (space.shape[0], rows, cols), np.uint8)
        actions = gym.spaces.Discrete(self.shape[0] * self.shape[1] * rows * cols)
        policy = type(self)(
            **{**self._get_constructor_parameters(), "observation_space": observations, "action_space": actions}
        )
        policy.load_state_dict(self.state_dict())
        policy.set_training_mode(False)
        return policy

    def _get_constructor_parameters(self) -> dict[str, Any]:
        return {
            "observation_space": self.observation_space,
            "action_space": self.action_space,
            "lr_schedule": self._dummy_schedule,
            "optimizer_class": self.optimizer_class,
            "optimizer_kwargs": self.optimizer_kwargs,
            **self.network_args,
        }


class HeightmapDQN(DQN):
    """DQN for ``HeightmapQPolicy``: masked exploration and TD targets, and a loss on the taken rotation only."""

    policy: HeightmapQPolicy

    def predict(
        self,
        observation: np.ndarray,
        state: tuple[np.ndarray, ...] | None = None,
        episode_start: np.ndarray | None = None,
        deterministic: bool = False,
    ) -> tuple[np.ndarray, tuple[np.ndarray, ...] | None]:
        if deterministic or np.random.rand() >= self.exploration_rate:
            return self.policy.predict(observation, state, episode_start, deterministic)
        batch = observation if observation.ndim == 4 else observation[None]
        actions = self.random_allowed(batch)
        return (actions if observation.ndim == 4 else actions[0]), state

    def random_allowed(self, observations: np.ndarray) -> np.ndarray:
        """(B,) actions drawn uniformly among those allowed on each encoded heightmap (B, C, H, W)."""
        with th.no_grad():
            allowed = self.q_net.allowed(th.as_tensor(observations, device=self.device)).cpu().numpy()
        return np.array([np.random.choice(np.flatnonzero(row)) for row in allowed])

    def _sample_action(
        self, learning_starts: int, action_noise: Any = None, n_envs: int = 1
    ) -> tuple[np.ndarray, np.ndarray]:
        # SB3's warm-up draws from the whole action space, nearly all of it cells of empty table; draw among the
        # allowed actions instead, as exploration does.
        if self.num_timesteps < learning_starts:
            actions = self.random_allowed(self._last_obs)
            return actions, actions
        return super()._sample_action(learning_starts, action_noise, n_envs)

    def train(self, gradient_steps: int, batch_size: int = 100) -> None:
        self.policy.set_training_mode(True)
        self._update_learning_rate(self.policy.optimizer)
        losses = []
        for _ in range(gradient_steps):
            data = self.replay_buffer.sample(batch_size, env=self._vec_normalize_env)  # type: ignore[union-attr]
            target = data.rewards.flatten()
            if self.gamma > 0:
                with th.no_grad():
                    following = data.next_observations
                    next_q = self.q_net_target(following).masked_fill(~self.q_net.allowed(following), -th.inf)
                    discounts = data.discounts.flatten() if data.discounts is not None else self.gamma
                    target = target + (1 - data.dones.flatten()) * discounts * next_q.max(1).values
            loss = F.smooth_l1_loss(self.q_net.q_at(data.observations, data.actions), target)
            losses.append(loss.item())
            self.policy.optimizer.zero_grad()
            loss.backward()
            th.nn.utils.clip_grad_norm_(self.policy.parameters(), self.max_grad_norm)
            self.policy.optimizer.step()
        self._n_updates += gradient_steps
        self.logger.record("train/n_updates", self._n_updates, exclude="tensorboard")
        self.logger.record("train/loss", float(np.mean(losses)))
