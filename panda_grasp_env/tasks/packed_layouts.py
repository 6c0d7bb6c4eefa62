"""Packed arrangements for the Grasp task: objects wedged so tightly that no top-down grasp fits until a push
separates them (VPG's and SPOT's hard test cases).

The open Panda hand needs a finger's room (12 mm thick, 20 mm wide) beside an object on both sides of the
axis it closes along, and spans at most 66 mm.  Every object here can be grasped on its own; packed with
3 mm gaps, each is blocked on at least one side of every axis it could be grasped across.  A grasp then
lands its fingers on the neighbours and closes on nothing.

``ADVERSARIAL_LAYOUTS`` are hand-designed (named, in a fixed order); ``random_packed_layout`` draws packed
grids for training.  Positions are metres in the layout's own frame (its centre at the origin), yaws
radians; ``lay_out`` jitters and places them in the workcell.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from panda_grasp_env.model.objects import PALETTE, ObjectShape

#: Gap between packed neighbours, metres: far less than a finger's 12 mm.
GAP = 0.003
#: Pose jitter of a hand-designed layout, per episode: the whole layout's centre (metres) and turn (radians),
#: and each object's position (metres, small enough to keep every gap open) and yaw (radians).
CENTRE_JITTER, TURN_JITTER = 0.01, np.deg2rad(10)
OBJECT_JITTER, OBJECT_YAW_JITTER = 0.001, np.deg2rad(2)

CUBE = ("cube", (0.025,))  # 5 cm
SMALL_CUBE = ("cube", (0.02,))  # 4 cm
CYLINDER = ("cylinder", (0.025, 0.03))  # 5 cm across, 6 cm tall
#: 9 x 3.5 x 4 cm: too long to grasp end to end, so only across its 3.5 cm width.
LONG_BOX = ("box", (0.045, 0.0175, 0.02))


@dataclass(frozen=True)
class Placement:
    """One object of a layout: ``kind`` and MuJoCo geom ``size`` (metres), centre ``x``, ``y`` (metres) and
    ``yaw`` (radians) in the layout's frame."""

    kind: str
    size: tuple[float, ...]
    x: float
    y: float
    yaw: float = 0.0


def _grid(rows: int, cols: int, shapes: list[tuple[str, tuple[float, ...]]]) -> tuple[Placement, ...]:
    """``rows`` x ``cols`` objects (row-major from ``shapes``, cycled) centred on the origin, packed: at the pitch
    that leaves ``GAP`` between the widest of them (cubes and cylinders: ``size[0]`` is the half-width)."""
    pitch = 2 * max(size[0] for _, size in shapes) + GAP
    return tuple(
        Placement(*shapes[(r * cols + c) % len(shapes)], (c - (cols - 1) / 2) * pitch, (r - (rows - 1) / 2) * pitch)
        for r in range(rows)
        for c in range(cols)
    )


def _rows_of_long_boxes(count: int, yaw: float = 0.0) -> tuple[Placement, ...]:
    """``count`` long boxes side by side (long sides touching) across the direction ``yaw``."""
    pitch = 2 * LONG_BOX[1][1] + GAP
    across = np.array([-math.sin(yaw), math.cos(yaw)])
    return tuple(Placement(*LONG_BOX, *((k - (count - 1) / 2) * pitch * across), yaw) for k in range(count))


def _walled_column(count: int) -> tuple[Placement, ...]:
    """A column of ``count`` cubes along y between two walls of long boxes laid end to end along y."""
    cubes = _grid(count, 1, [CUBE])
    offset = CUBE[1][0] + GAP + LONG_BOX[1][1]
    length = 2 * LONG_BOX[1][0] + GAP
    walls = [Placement(*LONG_BOX, side * offset, (k - 0.5) * length, math.pi / 2) for side in (-1, 1) for k in range(2)]
    return (*cubes, *walls)


def _brick_wall() -> tuple[Placement, ...]:
    """Two courses of long boxes along x, the second shifted half a box: no seam lines up."""
    length, width = 2 * LONG_BOX[1][0] + GAP, 2 * LONG_BOX[1][1] + GAP
    first = [Placement(*LONG_BOX, (k - 0.5) * length, -width / 2) for k in range(2)]
    second = [Placement(*LONG_BOX, (k - 1) * length, width / 2) for k in range(3)]
    return (*first, *second)


#: The hand-designed packed layouts, in a fixed order (an episode's ``layout`` indexes it).
ADVERSARIAL_LAYOUTS: dict[str, tuple[Placement, ...]] = {
    "cubes_2x2": _grid(2, 2, [CUBE]),
    "cubes_2x3": _grid(2, 3, [CUBE]),
    "cubes_3x3": _grid(3, 3, [CUBE]),
    "small_cubes_3x3": _grid(3, 3, [SMALL_CUBE]),
    "cylinders_2x2": _grid(2, 2, [CYLINDER]),
    "cubes_and_cylinders_3x3": _grid(3, 3, [CUBE, CYLINDER]),
    "long_boxes_2": _rows_of_long_boxes(2),
    "long_boxes_4": _rows_of_long_boxes(4),
    "long_boxes_5_diagonal": _rows_of_long_boxes(5, math.pi / 4),
    "cubes_between_walls": _walled_column(3),
    "brick_wall": _brick_wall(),
    "cube_row_against_boxes": (
        *_grid(1, 3, [CUBE]),
        *(
            Placement(*LONG_BOX, (k - 0.5) * (2 * LONG_BOX[1][0] + GAP), -(CUBE[1][0] + GAP + LONG_BOX[1][1]))
            for k in range(2)
        ),
    ),
}
#: Objects in the largest layout: the scene's object slots.
MAX_OBJECTS = max(max(len(layout) for layout in ADVERSARIAL_LAYOUTS.values()), 10)


def random_packed_layout(rng: np.random.Generator) -> tuple[Placement, ...]:
    """A packed layout for training: a grid of 2-3 rows by 2-4 columns (at most ``MAX_OBJECTS`` objects), half
    of them of one kind (5 cm cubes, 4 cm cubes or cylinders), half with the kind drawn per cell, at the pitch
    that leaves ``GAP`` between its widest objects; or 2-5 long boxes side by side."""
    if rng.random() < 0.25:
        return _rows_of_long_boxes(int(rng.integers(2, 6)))
    rows = int(rng.integers(2, 4))
    cols = int(rng.integers(2, 5))
    kinds = [CUBE, SMALL_CUBE, CYLINDER]
    if rng.random() < 0.5:
        kinds = [kinds[int(rng.integers(len(kinds)))]]
    shapes = [kinds[int(i)] for i in rng.integers(0, len(kinds), rows * cols)]
    return _grid(rows, cols, shapes)[:MAX_OBJECTS]


def jittered(
    layout: tuple[Placement, ...], rng: np.random.Generator, centre: np.ndarray, turn: float
) -> list[tuple[ObjectShape, np.ndarray, float]]:
    """(shape, world xy (metres), yaw (radians)) of each placement: the layout turned by ``turn`` about its
    centre, put at world ``centre``, each object moved by up to ``OBJECT_JITTER`` and turned by up to
    ``OBJECT_YAW_JITTER``.  Colours cycle through ``PALETTE``."""
    cos, sin = math.cos(turn), math.sin(turn)
    placed = []
    for index, p in enumerate(layout):
        offset = np.array([cos * p.x - sin * p.y, sin * p.x + cos * p.y])
        xy = centre + offset + rng.uniform(-OBJECT_JITTER, OBJECT_JITTER, 2)
        yaw = p.yaw + turn + rng.uniform(-OBJECT_YAW_JITTER, OBJECT_YAW_JITTER)
        placed.append((ObjectShape(p.kind, p.size, PALETTE[index % len(PALETTE)]), xy, float(yaw)))
    return placed
