"""Which way a tower fell, and which way a fall-dynamics predictor says it falls (``fall_directions``).

The truth comes from the blocks' poses, the predictions from the centroid of the block pixels in each
predictor's last frame, predicted from the first frames.
"""

from __future__ import annotations

from typing import Any

import numpy as np

from panda_grasp_env.agents.learning.falls.baselines import BASELINES, centroid
from panda_grasp_env.agents.learning.falls.model import FallPredictor, check_compatible, predict_batch
from panda_grasp_env.perception.camera import CameraModel

#: Horizontal shift (m) of a tower's mean block position, first frame to last, below which it did not fall.
FALL_SHIFT = 0.02
#: Predicted shift (pixels) of the block pixels' centroid below which a prediction gives no direction.
DIRECTION_MIN_PIXELS = 0.5
#: Angular error (degrees) up to which a predicted fall direction counts as right (``within_45`` of the results).
DIRECTION_TOLERANCE = 45.0


def image_to_world_direction(shift: np.ndarray, camera: dict[str, Any]) -> np.ndarray:
    """World-frame horizontal vectors (..., 2) (x, y) along image displacements ``shift`` (..., 2) (rows,
    columns; pixels) of a straight-down camera (``camera``: ``K``, and ``rotation`` camera -> world in OpenCV
    axes, as ``metadata.json`` holds them): each displacement as the camera-frame vector (columns / fx,
    rows / fy, 0) turned into the world.  A direction only: the length depends on depth, and parallax (points
    nearing the principal point as they fall away from the camera) is ignored."""
    K, rotation = np.asarray(camera["K"], dtype=float), np.asarray(camera["rotation"], dtype=float)
    shift = np.asarray(shift, dtype=float)
    along = np.stack([shift[..., 1] / K[0, 0], shift[..., 0] / K[1, 1], np.zeros(shift.shape[:-1])], -1)
    return (along @ rotation.T)[..., :2]


def angle_between(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """Unsigned angles (degrees, 0-180) between 2-D vectors ``a`` and ``b`` (..., 2)."""
    turn = np.arctan2(a[..., 1], a[..., 0]) - np.arctan2(b[..., 1], b[..., 0])
    return np.degrees(np.abs((turn + np.pi) % (2 * np.pi) - np.pi))


def fall_directions(
    model: FallPredictor | None,
    labels: np.ndarray,
    poses: np.ndarray,
    n_blocks: np.ndarray,
    crop_origin: np.ndarray,
    camera: dict[str, Any],
    classes: list[str],
    context: int,
    depth: np.ndarray | None = None,
    batch_size: int = 64,
) -> dict[str, Any]:
    """Which way each tower fell, predicted from its first frames, against what happened.

    Sequences: ``labels`` (N, T, S, S) cut at ``crop_origin`` (N, 2) (column, row) from the renders of the
    overhead ``camera`` of ``metadata.json`` (``render_size``, ``K``, ``rotation``, ``position``), block
    ``poses`` (N, T, B, 7) (world frame, metres; rows past a sequence's ``n_blocks`` are ignored); ``depth``
    (N, T, S, S) for a ``use_depth`` model.  With t = max(context - 1, 1), the newest context frame as in
    ``evaluate``:

    * true direction: the horizontal (x, y) displacement, in the world frame, of the mean position of the
      sequence's blocks from frame 0 to frame T - 1, over the blocks whose centre lies inside the crop in
      frame T - 1.  A tower whose mean moved under ``FALL_SHIFT`` did not fall: it is counted in
      ``did_not_fall`` and not scored (so is a tower that stood while a struck block flew out of view).  The
      world frame and the poses, not the images, because they say where the blocks went: the pixels see
      only the blocks' visible faces, and the top of a tall tower seen from above sits off its base by
      parallax.
    * predicted direction: the centroid of every block pixel (any block class) of the predictor's frame
      T - 1, predicted from frames up to t (the model rolled out T - 1 - t steps from frames
      t - context + 1 ... t; a baseline of ``BASELINES`` called with (t, T - 1 - t)), minus the centroid of
      the block pixels of the true frame 0, in image coordinates, turned into a world direction by
      ``image_to_world_direction``.  A fallen tower of whose blocks frame 0 shows no pixel (the arm of a
      push above it) gives no predictor a place to start: it is counted in ``hidden`` and not scored.  Under
      ``DIRECTION_MIN_PIXELS`` of shift, or with no block pixel in the predicted frame, a prediction has no
      direction: counted in ``no_direction`` and scored as 180 degrees.
    * ``true_labels``, a reference rather than a predictor: the true frame T - 1 through the same mapping,
      what a perfect segmentation predictor scores; its shortfall is the mapping's (occlusion, parallax,
      blocks leaving the crop).

    Per predictor, over the ``scored`` sequences (the tower fell and frame 0 shows it): ``within_45``, the
    fraction whose angular error is at most ``DIRECTION_TOLERANCE`` degrees, and ``median_error_deg``.  The
    summary covers all sequences and, where they hold several tower heights, each height (``by_height``,
    keyed by the number of blocks).
    """
    n, length = labels.shape[:2]
    t = max(context - 1, 1)
    horizon = length - 1 - t
    if horizon < 1:
        raise ValueError(f"sequences of {length} frames leave nothing to predict after context {context}")
    ends = {name: np.stack([baseline(labels[i], t, horizon) for i in range(n)]) for name, baseline in BASELINES.items()}
    if model is not None:
        check_compatible(model, labels, classes, depth)
        model.eval()
        windows = labels[:, t - context + 1 : t + 1]
        contexts = depth[:, t - context + 1 : t + 1] if model.use_depth else None
        ends["model"] = predict_batch(model, windows, horizon, contexts, batch_size)[:, -1]
    ends["true_labels"] = labels[:, -1]
    start = [centroid(frame > 0) for frame in labels[:, 0]]
    view = CameraModel(
        *camera["render_size"], *(np.asarray(camera[k], dtype=float) for k in ("K", "rotation", "position"))
    )
    truth = np.zeros((n, 2))
    for i in range(n):
        blocks = poses[i, :, : n_blocks[i], :3]
        pixels = view.world_to_pixel(blocks[-1])[0] - crop_origin[i]  # (column, row) in the crop
        seen = np.all((pixels >= -0.5) & (pixels < labels.shape[-1] - 0.5), axis=1)
        if seen.any():
            truth[i] = (blocks[-1, seen, :2] - blocks[0, seen, :2]).mean(0)
    fell = np.hypot(*truth.T) >= FALL_SHIFT
    errors = {}
    for name, frames in ends.items():
        error = np.full(n, np.nan)  # NaN: no direction
        for i, frame in enumerate(frames):
            end = centroid(frame > 0)
            if start[i] is not None and end is not None and np.hypot(*(end - start[i])) >= DIRECTION_MIN_PIXELS:
                error[i] = angle_between(image_to_world_direction(end - start[i], camera), truth[i])
        errors[name] = error

    seen = np.array([first is not None for first in start])

    def summary(chosen: np.ndarray) -> dict[str, Any]:
        scored = chosen & fell & seen
        predictors = {}
        for name, error in errors.items():
            worst = np.where(np.isnan(error[scored]), 180.0, error[scored])
            predictors[name] = {
                "within_45": round(float(np.mean(worst <= DIRECTION_TOLERANCE)), 4) if scored.any() else None,
                "median_error_deg": round(float(np.median(worst)), 1) if scored.any() else None,
                "no_direction": int(np.isnan(error[scored]).sum()),
            }
        return {
            "sequences": int(chosen.sum()),
            "did_not_fall": int((chosen & ~fell).sum()),
            "fell": int((chosen & fell).sum()),
            "hidden": int((chosen & fell & ~seen).sum()),
            "scored": int(scored.sum()),
            "predictors": predictors,
        }

    result = summary(np.ones(n, dtype=bool))
    heights = np.unique(n_blocks)
    if len(heights) > 1:
        result["by_height"] = {str(int(h)): summary(n_blocks == h) for h in heights}
    return result
