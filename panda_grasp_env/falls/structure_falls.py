"""Structure falls: what a piece set down on a partly built structure does next, from rest, in the falls
dataset format (``shards.py``), for the learned stability check (``agents/policies/learned_physics.py``).

A sequence (``RecorderSettings(scene="structures")``): ``PandaStructure-v0`` resets with its seed to a random
structure of the generator (tiers 1-4, up to ``MAX_PIECES`` pieces; never one resembling the named suite).
Some of its pieces are set exactly at their targets -- a prefix of a build order in which every piece's
supports come first -- and then one more, the candidate: half the time one whose supports are all set
(``ready``), otherwise one that lacks a support where the structure has one (it hangs in the air).  With
``shifted_candidates`` it is drawn in thirds: in the air; ready, at its target; or ready and resting on others,
slid off its target (``shifted_off``) so that it may overhang its supports.  The
pieces are let go at rest, and the overhead camera is sampled from that instant every ``frame_interval``
seconds, cropped around the candidate as the check crops it; the physics runs as ``sim.stability.what_if``
runs it (the arm holds its controls).  A ready candidate at its target stands (the generator's structures
stand at every build step); one in the air falls; a shifted one stands or tips as its centre of mass lies over
its supports or beyond them -- the overhangs and counterweights a planner asks about.

Labels are the check's: class k + 1 is the k-th highest piece set (at rest), 0 everything else; ``poses``
follows the same order.  ``colour_labels`` repeats ``labels`` (the pieces' colours are not distinct);
``breaker`` is 255 (nothing struck) and ``strike`` holds the candidate's rank, its heading (radians), 0, and
its x, y (world metres).
"""

from __future__ import annotations

from collections.abc import Sequence
from typing import Any

import mujoco
import numpy as np

from panda_grasp_env.falls.settings import RENDER_SIZE, RecorderSettings
from panda_grasp_env.model.structure_generator import MAX_PIECES
from panda_grasp_env.model.structures import Piece, interpenetrate
from panda_grasp_env.perception.camera import CameraModel
from panda_grasp_env.sim.stability import set_free_pose
from panda_grasp_env.tasks.structure_build import resting_on

#: ``breaker`` of a structure sequence: nothing struck it.
NOT_STRUCK = 255
#: The camera the sequences are rendered from.
CAMERA = "overhead"


def crop_origin(camera: CameraModel, centre: np.ndarray, size: int) -> tuple[int, int]:
    """(column, row) of the corner of a ``size``-pixel square crop of a ``RENDER_SIZE`` image centred on world
    point ``centre`` (metres), kept inside the image."""
    (u, v), _ = camera.world_to_pixel(np.asarray(centre, dtype=float))
    width, height = RENDER_SIZE
    return int(np.clip(round(u) - size // 2, 0, width - size)), int(np.clip(round(v) - size // 2, 0, height - size))


def height_order(data: mujoco.MjData, watched: Sequence[int], most: int) -> list[int]:
    """The ``most`` highest of bodies ``watched``, highest first (ties in the order given)."""
    return sorted(map(int, watched), key=lambda body: -data.xpos[body, 2])[:most]


def ranked_labels(model: mujoco.MjModel, geoms: np.ndarray, order: Sequence[int]) -> np.ndarray:
    """Labels (uint8, the shape of ``geoms``, a segmentation render's geom ids): k + 1 where body ``order[k]``
    shows, 0 elsewhere."""
    body_of_geom = np.append(model.geom_bodyid, -1)  # geom id -1 (no geom) -> body -1
    bodies = body_of_geom[geoms]
    labels = np.zeros(geoms.shape, dtype=np.uint8)
    for rank, body in enumerate(order):
        labels[bodies == body] = rank + 1
    return labels


def make_structure_env() -> Any:
    """The env whose random structures the sequences are set from."""
    import gymnasium as gym

    import panda_grasp_env  # noqa: F401

    return gym.make(
        "PandaStructure-v0", structure="random", max_pieces=MAX_PIECES, obs_mode="state", action_mode="primitive"
    )


#: What a structure sequence's candidate is (its ``candidate_kind`` in the shards): set over a missing support;
#: at its target with its supports set; or resting on set pieces, slid off its target (``shifted_off``).
CANDIDATE_KINDS = ("in_the_air", "ready", "shifted")


def build_state(
    pieces: list[Piece], rng: np.random.Generator, shifted: bool = False
) -> tuple[list[int], int, np.ndarray, int]:
    """The pieces set before the candidate (indices into ``pieces``, world poses: a build-order prefix, each
    piece after those it rests on), the candidate, the candidate's offset from its target (x, y, world
    metres; zero unless ``shifted`` draws it slid off, module doc) and its kind (an index into
    ``CANDIDATE_KINDS``)."""
    below = {
        j: [i for i in range(len(pieces)) if i != j and resting_on(pieces[i], [pieces[j]])] for j in range(len(pieces))
    }
    built: list[int] = []
    for _ in range(int(rng.integers(0, len(pieces)))):
        ready = [j for j in range(len(pieces)) if j not in built and all(i in built for i in below[j])]
        built.append(int(rng.choice(ready)))
    left = [j for j in range(len(pieces)) if j not in built]
    ready = [j for j in left if all(i in built for i in below[j])]
    unready = [j for j in left if j not in ready]
    if shifted:
        draw = rng.random()
        in_the_air = bool(unready) and draw < 1 / 3
    else:
        in_the_air = bool(unready) and rng.random() >= 0.5
    if in_the_air:
        return built, int(rng.choice(unready)), np.zeros(2), CANDIDATE_KINDS.index("in_the_air")
    candidate = int(rng.choice(ready))
    offset = (
        shifted_off(pieces, built, candidate, rng) if shifted and below[candidate] and draw >= 2 / 3 else np.zeros(2)
    )
    return built, candidate, offset, CANDIDATE_KINDS.index("shifted" if offset.any() else "ready")


def shifted_off(pieces: list[Piece], built: list[int], candidate: int, rng: np.random.Generator) -> np.ndarray:
    """An offset (x, y, world metres) sliding ``pieces[candidate]`` off its target: up to 1.5 of its half-length
    along its own axes, so its centre of mass may leave its supports, and overlapping no piece of ``built``;
    zero if none of four draws does."""
    piece = pieces[candidate]
    c, s = np.cos(piece.yaw), np.sin(piece.yaw)
    for _ in range(4):
        along, across = rng.uniform(-1.5, 1.5, 2) * piece.half_extents[:2]
        offset = np.array([c * along - s * across, s * along + c * across])
        x, y, z = piece.position
        moved = Piece(piece.kind, (x + offset[0], y + offset[1], z), piece.yaw)
        if not any(interpenetrate(moved, pieces[i]) for i in built):
            return offset
    return np.zeros(2)


class StructureRecorder:
    """Records structure sequences in one process: the env and renderer are made once."""

    def __init__(self) -> None:
        from panda_grasp_env.sim.rendering import CameraRenderer

        self.env = make_structure_env()
        cell = self.env.unwrapped.cell
        self.renderer = CameraRenderer(cell.model, *RENDER_SIZE, "fast")

    def frame(self, order: list[int], origin: tuple[int, int], crop: int) -> dict[str, np.ndarray]:
        cell = self.env.unwrapped.cell
        rgb, depth = self.renderer.render_rgbd(cell.data, CAMERA)
        geoms = self.renderer.render(cell.data, CAMERA, "segmentation")
        u0, v0 = origin
        window = (slice(v0, v0 + crop), slice(u0, u0 + crop))
        labels = ranked_labels(cell.model, geoms[window], order)
        poses = np.full((MAX_PIECES, 7), np.nan, dtype=np.float32)
        poses[: len(order)] = np.concatenate([cell.data.xpos[order], cell.data.xquat[order]], axis=1)
        return {
            "rgb": np.ascontiguousarray(rgb[window]),
            "depth": depth[window].astype(np.float16),
            "labels": labels,
            "colour_labels": labels.copy(),
            "poses": poses,
        }

    def record(self, seed: int, settings: RecorderSettings) -> dict[str, np.ndarray]:
        """One sequence (module doc) from reset seed ``seed``."""
        self.env.reset(seed=seed)
        task, cell = self.env.unwrapped.task, self.env.unwrapped.cell
        structure, layout = task.structure, task.layout
        centres, yaws = structure.world_poses(layout.origin, layout.heading)
        pieces = [Piece(p.kind, tuple(c), float(y)) for p, c, y in zip(structure.pieces, centres, yaws)]
        rng = np.random.default_rng([settings.seed, seed, 0x57AB])
        built, candidate, offset, kind = build_state(pieces, rng, settings.shifted_candidates)
        centres = np.array(centres, dtype=float)
        centres[candidate, :2] += offset
        bodies = cell.object_ids[: len(pieces)]
        for index in [*built, candidate]:
            set_free_pose(cell.model, cell.data, int(bodies[index]), centres[index], float(yaws[index]))
        mujoco.mj_forward(cell.model, cell.data)
        set_bodies = [int(bodies[i]) for i in [*built, candidate]]
        order = height_order(cell.data, set_bodies, MAX_PIECES)
        camera = CameraModel.from_mujoco(cell.model, cell.data, CAMERA, *RENDER_SIZE)
        origin = crop_origin(camera, centres[candidate], settings.crop)
        frames = [self.frame(order, origin, settings.crop)]
        steps = int(round(settings.frame_interval / cell.model.opt.timestep))
        while len(frames) < settings.frames:
            mujoco.mj_step(cell.model, cell.data, nstep=steps)  # as sim.stability.what_if runs a candidate
            frames.append(self.frame(order, origin, settings.crop))
        stacked = {key: np.stack([frame[key] for frame in frames]) for key in frames[0]}
        x, y, _ = centres[candidate]
        rank = order.index(int(bodies[candidate]))
        return {
            **stacked,
            "n_blocks": np.uint8(len(order)),
            "seeds": np.int64(seed),
            "breaker": np.uint8(NOT_STRUCK),
            "strike": np.array([rank, yaws[candidate], 0.0, x, y], dtype=np.float32),
            "crop_origin": np.array(origin, dtype=np.int32),
            "candidate_kind": np.uint8(kind),
        }

    def camera(self) -> CameraModel:
        cell = self.env.unwrapped.cell
        return CameraModel.from_mujoco(cell.model, cell.data, CAMERA, *RENDER_SIZE)

    def close(self) -> None:
        self.renderer.close()
        self.env.close()
