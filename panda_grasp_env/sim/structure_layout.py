"""Where a structure episode's pieces stand and lie: a seeded site for the structure and places for its loose
pieces (``draw_layout``), and standing pieces in a workcell's object slots (``stand_pieces``).  World frame,
metres, radians."""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass

import mujoco
import numpy as np

from panda_grasp_env.geometry import yaw_quaternion
from panda_grasp_env.model.structures import BLOCK_KINDS, Piece, Structure, footprints_within
from panda_grasp_env.sim.workcell import SPAWN_REGION, Workcell


def stand_pieces(
    cell: Workcell,
    structure: Structure,
    pieces: Sequence[Piece],
    slots: Sequence[int],
    origin: Sequence[float],
    heading: float,
) -> None:
    """Give object slots ``slots`` (body ids, one per piece) the shapes of ``pieces`` and stand each, at rest,
    at its pose in ``structure``'s frame placed at table point ``origin`` (x, y; metres) turned by ``heading``
    (radians).  Other slots keep their shapes and poses."""
    if len(slots) != len(pieces):
        raise ValueError(f"{len(pieces)} pieces need as many object slots, got {len(slots)}")
    if not pieces:
        return
    cell.set_object_shapes({int(body): piece.shape() for body, piece in zip(slots, pieces)})
    positions, yaws = structure.world_poses(origin, heading, pieces)
    for body, position, yaw in zip(slots, positions, yaws):
        cell.set_body_pose(int(body), position, yaw_quaternion(float(yaw)))
    mujoco.mj_forward(cell.model, cell.data)  # poses and contacts read right after are current


#: Room (metres) kept between loose pieces (a finger's width and more), and between a loose piece and the
#: structure's footprint: the arm's wrist reaches ~4.5 cm ahead of the hand, and grasping a cube 3 cm from a
#: tall tower's site it struck the tower (6 cm from an eight-cube tower, its wrist struck it too).
LOOSE_CLEARANCE, SITE_CLEARANCE = 0.03, 0.08
#: Where loose pieces lie (x and y intervals, metres): the spawn region widened within the top-down grasps'
#: reach, so that a structure of eight pieces and its eight loose pieces fit; and no farther than
#: ``LOOSE_REACH`` (metres, every corner) from the robot's base, as far as the spawn region's far corners (a
#: grasp 70 cm out missed its cube).
LOOSE_REGION, LOOSE_REACH = np.array([[0.28, 0.72], [-0.32, 0.32]]), 0.68
#: Margin (metres) between a structure's footprint and the spawn region's edges.
SITE_MARGIN = 0.02
#: Draws of a site or of a loose piece before a layout starts over, and layouts before giving up.
LAYOUT_DRAWS, LAYOUT_ATTEMPTS = 500, 200


@dataclass(frozen=True)
class StructureLayout:
    """Where an episode's structure stands (``origin``, table point, metres; ``heading``, radians) and where its
    loose pieces lie: ``loose_positions`` (n, 3) centres and ``loose_yaws`` (n,), world frame, one per
    ``loose`` kind, in order."""

    origin: tuple[float, float]
    heading: float
    loose: tuple[Piece, ...]
    loose_positions: np.ndarray
    loose_yaws: np.ndarray


def _radius(kind: str) -> float:
    """Radius of a piece's footprint about its centre, metres."""
    hx, hy, _ = BLOCK_KINDS[kind]
    return float(np.hypot(hx, hy))


def draw_layout(
    rng: np.random.Generator,
    structure: Structure,
    loose: Sequence[Piece],
    site_region: np.ndarray = SPAWN_REGION,
    loose_region: np.ndarray = LOOSE_REGION,
) -> StructureLayout:
    """A seeded site for ``structure`` whose footprint lies ``SITE_MARGIN`` inside ``site_region`` (x and y
    intervals, metres), at a uniform heading, and places in ``loose_region`` for the ``loose`` pieces (their
    kinds; positions are drawn) that keep ``SITE_CLEARANCE`` from the footprint and ``LOOSE_CLEARANCE`` from
    each other.
    ``ValueError`` if ``LAYOUT_ATTEMPTS`` layouts found no room."""
    for _ in range(LAYOUT_ATTEMPTS):
        site = _draw_site(rng, structure, site_region)
        if site is None:
            continue
        origin, heading = site
        positions, yaws = structure.world_poses(origin, heading)
        site = [Piece(p.kind, tuple(xyz), float(yaw)) for p, xyz, yaw in zip(structure.pieces, positions, yaws)]
        placed: list[Piece] = []
        for piece in loose:
            r = _radius(piece.kind)
            for _ in range(LAYOUT_DRAWS):
                xy = [rng.uniform(*(loose_region[0] + [r, -r])), rng.uniform(*(loose_region[1] + [r, -r]))]
                candidate = Piece(piece.kind, (*xy, BLOCK_KINDS[piece.kind][2]), float(rng.uniform(-np.pi, np.pi)))
                reach = np.linalg.norm(candidate.corners(), axis=1).max()
                crowded = any(footprints_within(candidate, o, SITE_CLEARANCE) for o in site) or any(
                    footprints_within(candidate, o, LOOSE_CLEARANCE) for o in placed
                )
                if reach <= LOOSE_REACH and not crowded:
                    break
            else:
                break
            placed.append(candidate)
        else:
            return StructureLayout(
                origin,
                heading,
                tuple(loose),
                np.array([p.position for p in placed]).reshape(-1, 3),
                np.array([p.yaw for p in placed]),
            )
    raise ValueError(f"no room for structure {structure.name!r} and {len(loose)} loose pieces in the region")


def _draw_site(
    rng: np.random.Generator, structure: Structure, region: np.ndarray
) -> tuple[tuple[float, float], float] | None:
    corners = np.concatenate([p.corners() for p in structure.pieces])
    for _ in range(LAYOUT_DRAWS):
        heading = float(rng.uniform(-np.pi, np.pi))
        c, s = np.cos(heading), np.sin(heading)
        turned = corners @ np.array([[c, s], [-s, c]])
        low = region[:, 0] + SITE_MARGIN - turned.min(axis=0)
        high = region[:, 1] - SITE_MARGIN - turned.max(axis=0)
        if np.all(low <= high):
            return (float(rng.uniform(low[0], high[0])), float(rng.uniform(low[1], high[1]))), heading
    return None


def lay_out_start(cell: Workcell, structure: Structure, rng: np.random.Generator) -> tuple[StructureLayout, np.ndarray]:
    """Clear ``cell`` and lay out an episode's start, at rest: ``structure`` standing at a drawn site (a
    prebuilt one; its layout's loose places are free spots for the pieces to remove), or every piece, the
    scaffold's too, loose (``draw_layout``).  Returns the layout and the object slots (body ids) holding the
    structure's pieces in order, then the scaffold's."""
    cell.clear()
    slots = cell.object_ids[: len(structure.kinds)]
    if structure.prebuilt:
        layout = draw_layout(rng, structure, [structure.pieces[i] for i in structure.removed])
        stand_pieces(cell, structure, structure.pieces, slots, layout.origin, layout.heading)
    else:
        layout = draw_layout(rng, structure, structure.pieces + structure.scaffold)
        cell.set_object_shapes({int(b): p.shape() for b, p in zip(cell.object_ids, layout.loose)})
        for body, position, yaw in zip(cell.object_ids, layout.loose_positions, layout.loose_yaws):
            cell.set_body_pose(int(body), position, yaw_quaternion(float(yaw)))
        mujoco.mj_forward(cell.model, cell.data)
    cell.settle(0.3)
    return layout, slots
