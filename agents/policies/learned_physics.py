"""Will it stand?  Asked of the learned fall model instead of the simulator.

``FallModelCheck`` has the signature of ``sim.stability.what_if``: it sets the candidate's pieces in a copy of
the simulation, but instead of running the physics it renders the overhead camera once (the simulator's
segmentation of the watched pieces as block classes, and depth), hands that frame to the fall model
(``agents.learning.falls.model``) as its context -- the pieces are at rest, so every context frame is that
frame -- and reads the displacement the model plans for each block over its next frames.  A model with a
settle head (``SettleHead``) answers instead with the largest displacement it predicts of any block from that
frame alone.  A predicted displacement of ``threshold`` metres or more means "falls".
``planned_lookahead_learned`` is the structure lookahead planner with this check in place of ``what_if``: the
same orders, scaffold search and budget.

Pixels are the recorder's: a ``crop`` x ``crop`` window of the ``RENDER_SIZE`` overhead image (about 5 mm a
pixel at the table), centred on the candidate piece, labelled by height as the structure-fall recorder labels
its sequences (``falls.structure_falls``).  World frame, metres.
"""

from __future__ import annotations

import copy
from collections.abc import Mapping, Sequence
from dataclasses import dataclass
from pathlib import Path

import gymnasium as gym
import mujoco
import numpy as np

from panda_grasp_env.agents.policies.registry import register_agent
from panda_grasp_env.agents.policies.structure_views import HeightmapPieces
from panda_grasp_env.agents.policies.structures import STRUCTURE_BENCHMARKS, StructurePlanner
from panda_grasp_env.falls.structure_falls import CAMERA, crop_origin, height_order, ranked_labels
from panda_grasp_env.perception.camera import CameraModel
from panda_grasp_env.sim.rendering import CameraRenderer
from panda_grasp_env.sim.stability import STILL_SHIFT, set_free_pose
from panda_grasp_env.tooling.extras import require_learning_stack

#: The shipped fall model the check asks by default: the structure-fall model with a settle head (trained on
#: structure falls with shifted candidates; benchmarks/learned_stability.py compares it with the others).
DEFAULT_FALL_MODEL = "fall_convlstm_structures_settle"
#: Predicted displacement (metres, largest over the pieces) at or above which a candidate counts as falling:
#: the simulator's own (``sim.stability.STILL_SHIFT``).  One pixel of the recorder's crop is ~5 mm.
DEFAULT_THRESHOLD = STILL_SHIFT


@dataclass(frozen=True)
class Prediction:
    """What the fall model predicts of a candidate: the largest planned displacement of a watched piece
    (metres) over ``seconds`` of predicted frames, and the threshold it is judged against."""

    shift: float
    threshold: float
    seconds: float

    @property
    def stands(self) -> bool:
        """Whether every watched piece is planned to move less than ``threshold``."""
        return self.shift < self.threshold


class FallModelCheck:
    """``what_if``'s stand-in that asks a fall model (a shipped one by name, or a ``model.pt`` path)."""

    def __init__(self, fall_model: str | Path = DEFAULT_FALL_MODEL, threshold: float = DEFAULT_THRESHOLD) -> None:
        require_learning_stack("the learned stability check")
        from panda_grasp_env.agents.learning.falls.model import load_fall_model
        from panda_grasp_env.agents.learning.falls.records import FALL_CHECKPOINTS
        from panda_grasp_env.falls.settings import RENDER_SIZE

        if not (isinstance(threshold, (int, float)) and np.isfinite(threshold) and threshold > 0):
            raise ValueError(f"threshold must be a positive number of metres, got {threshold!r}")
        path = Path(fall_model)
        if path.suffix != ".pt":
            path = FALL_CHECKPOINTS / str(fall_model) / "model.pt"
        self.net, saved = load_fall_model(path)
        self.net.eval()
        if not (self.net.track_horizon or self.net.settle_frames):
            raise ValueError(
                f"{path}: the check reads a fall model's settle head or planned displacements (a track head)"
            )
        self.threshold = float(threshold)
        self.horizon = self.net.settle_frames or self.net.track_horizon  # frames the answer spans
        self.frame_interval = float(saved.get("frame_interval", 0.04))
        self.width, self.height = RENDER_SIZE
        self._renderer: CameraRenderer | None = None

    def _render(self, model: mujoco.MjModel, data: mujoco.MjData) -> tuple[np.ndarray, np.ndarray]:
        if self._renderer is None or self._renderer.model is not model:
            self._renderer = CameraRenderer(model, self.width, self.height, "fast")
        _, depth = self._renderer.render_rgbd(data, CAMERA)
        return self._renderer.render(data, CAMERA, "segmentation"), depth

    def frame(
        self, model: mujoco.MjModel, data: mujoco.MjData, centre: np.ndarray, watched: Sequence[int]
    ) -> tuple[np.ndarray, np.ndarray, float]:
        """Labels (S, S; 0 background, k + 1 the k-th highest watched body) and depth (S, S; metres) of the
        crop centred on world point ``centre``, and the metres a pixel spans at ``centre``'s height."""
        geoms, depth = self._render(model, data)
        size = self.net.image_size
        camera = CameraModel.from_mujoco(model, data, CAMERA, self.width, self.height)
        u0, v0 = crop_origin(camera, centre, size)
        window = (slice(v0, v0 + size), slice(u0, u0 + size))
        labels = ranked_labels(model, geoms[window], height_order(data, watched, self.net.n_classes - 1))
        _, distance = camera.world_to_pixel(np.asarray(centre, dtype=float))
        metres_per_pixel = float(distance) / camera.K[0, 0]
        return labels.astype(np.int64), depth[window], metres_per_pixel

    def predict(self, labels: np.ndarray, depth: np.ndarray) -> np.ndarray:
        """Each block class's planned displacement (K, 2; pixels) over the model's horizon, from one frame at
        rest taken as every context frame."""
        import torch

        from panda_grasp_env.agents.learning.falls.model import model_inputs

        context = self.net.context
        with torch.no_grad():
            frames = model_inputs(
                self.net,
                np.repeat(labels[None, None], context, axis=1),
                np.repeat(depth[None, None], context, axis=1).astype(np.float32),
            )
            _, steps, _ = self.net.rollout_tracks(frames, self.horizon)
        return steps.sum(1)[0].numpy()

    def __call__(
        self,
        model: mujoco.MjModel,
        data: mujoco.MjData,
        moves: Mapping[int, tuple[np.ndarray, float]],
        watched: Sequence[int],
    ) -> Prediction:
        trial = copy.copy(data)
        for body, (position, yaw) in moves.items():
            set_free_pose(model, trial, int(body), np.asarray(position, dtype=float), float(yaw))
        mujoco.mj_forward(model, trial)
        watched = sorted({*map(int, watched), *map(int, moves)})
        centre = np.mean([np.asarray(position, dtype=float) for position, _ in moves.values()], axis=0)
        labels, depth, metres_per_pixel = self.frame(model, trial, centre, watched)
        shift = self.largest_shift(labels, depth, len(watched), metres_per_pixel)
        return Prediction(shift, self.threshold, self.horizon * self.frame_interval)

    def largest_shift(self, labels: np.ndarray, depth: np.ndarray, n_watched: int, metres_per_pixel: float) -> float:
        """The largest displacement (metres) predicted of the block classes 1..``n_watched`` that show in the
        frame (``predict``'s inputs; ``metres_per_pixel`` converts the track head's plan): the settle head's
        answer if the model has one, else the largest planned displacement."""
        if self.net.settle_frames:
            import torch

            from panda_grasp_env.agents.learning.falls.model import model_inputs

            with torch.no_grad():
                frame = model_inputs(self.net, labels[None, None], depth[None, None].astype(np.float32))[:, 0]
                return float(self.net.settle_shift(frame)[0])
        present = [k for k in range(1, min(n_watched, self.net.n_classes - 1) + 1) if np.any(labels == k)]
        planned = self.predict(labels, depth)
        return max((float(np.linalg.norm(planned[k - 1])) for k in present), default=0.0) * metres_per_pixel


@register_agent("planned_lookahead_learned", *STRUCTURE_BENCHMARKS, needs_learning_stack=True)
def learned_lookahead_planner(env: gym.Env, seed: int) -> StructurePlanner:
    """``planned_lookahead_learned``: ``planned_lookahead`` asking the shipped fall model, not the simulator."""
    return StructurePlanner(HeightmapPieces(), lookahead=True, env=env, check=FallModelCheck())
