"""The named structures, tier by tier (``structures.TIERS``): a test-only suite.

No training, tuning or selection may use these: random training structures come from a generator of the
tiers' motifs, never from this list.  Every structure here stands when laid out exactly (checked in
simulation by the suite's tests, as is every partial build it lists as ``unstable``).

Frames and units as in ``structures``: metres, radians, the structure's frame on the table top.
"""

from __future__ import annotations

from collections.abc import Mapping
from typing import Any

import numpy as np

from panda_grasp_env.model.structures import BLOCK_KINDS, Piece, Structure

#: A cube's edge, and the centre-to-centre pitch of cubes side by side: 5 mm apart, room for a cube
#: lowered between two others to turn a few degrees (1 mm apart, a place between neighbours caught on one).
EDGE = 2 * BLOCK_KINDS["cube"][0]
PITCH = EDGE + 0.005
#: Half a plank's length.
PLANK_HALF = BLOCK_KINDS["plank"][0]


def level(k: float) -> float:
    """Height of the centre of a cube-high piece on ``k`` cube-high layers, metres."""
    return EDGE / 2 + k * EDGE


def cube(x: float, y: float, k: float) -> Piece:
    return Piece("cube", (x, y, level(k)))


def plank(x: float, y: float, k: float, yaw: float = 0.0) -> Piece:
    return Piece("plank", (x, y, level(k)), yaw)


def _tower(n: int) -> Structure:
    return Structure(f"tower_{n}", tuple(cube(0.0, 0.0, k) for k in range(n)), 1, f"a tower of {n} cubes")


def _layouts() -> list[Structure]:
    row = tuple(cube(x * PITCH, 0.0, 0) for x in (-1, 0, 1))
    ell = tuple(cube(x * PITCH, y * PITCH, 0) for x, y in ((-1, -1), (0, -1), (1, -1), (-1, 0), (-1, 1)))
    ring = tuple(cube(x * PITCH, y * PITCH, 0) for x in (-1, 0, 1) for y in (-1, 0, 1) if (x, y) != (0, 0))
    pyramid = (
        *(cube(x * PITCH, 0.0, 0) for x in (-1, 0, 1)),
        *(cube(x * PITCH, 0.0, 1) for x in (-0.5, 0.5)),
        cube(0.0, 0.0, 2),
    )
    wall = (*(cube(x * PITCH, 0.0, 0) for x in (-1.5, -0.5, 0.5, 1.5)), *(cube(x * PITCH, 0.0, 1) for x in (-1, 0, 1)))
    return [
        Structure("row_3", row, 2, "three cubes in a row"),
        Structure("ell_5", ell, 2, "an L of five cubes, arms of three"),
        # Corners first: a corner placed last has neighbours on both sides the fingers would close on.
        Structure(
            "ring_8", ring, 2, "a square ring of eight cubes around an empty centre", order=(0, 2, 5, 7, 1, 3, 4, 6)
        ),
        Structure("pyramid_6", pyramid, 2, "a 3-2-1 pyramid, one cube thick"),
        Structure("wall_7", wall, 2, "a staggered wall: four cubes, three on their joints"),
    ]


#: Pillars under a plank's ends: centred this far (metres) from the plank's centre, flush with its ends.
PILLAR_OFFSET = PLANK_HALF - EDGE / 2


def _spans() -> list[Structure]:
    bridge = (cube(-PILLAR_OFFSET, 0.0, 0), cube(PILLAR_OFFSET, 0.0, 0), plank(0.0, 0.0, 1))
    portal = (
        *(cube(x, 0.0, k) for x in (-PILLAR_OFFSET, PILLAR_OFFSET) for k in (0, 1)),
        plank(0.0, 0.0, 2),
    )
    # Four legs, a beam along x on each pair, and the top across the beams.
    legs = (cube(x, y, 0) for x in (-PILLAR_OFFSET, PILLAR_OFFSET) for y in (-PILLAR_OFFSET, PILLAR_OFFSET))
    beams = (plank(0.0, y, 1) for y in (-PILLAR_OFFSET, PILLAR_OFFSET))
    table = (*legs, *beams, plank(0.0, 0.0, 2, np.pi / 2))
    # Two planks end to end, 5 mm apart, over three pillars: the middle one carries an end of each.
    centre = PLANK_HALF + 0.0025
    outer = centre + PILLAR_OFFSET
    two_span = (
        *(cube(x, 0.0, 0) for x in (-outer, 0.0, outer)),
        *(plank(x, 0.0, 1) for x in (-centre, centre)),
    )
    return [
        Structure("bridge", bridge, 3, "a plank across two one-cube pillars"),
        Structure("portal", portal, 3, "a plank across two two-cube pillars"),
        Structure("table", table, 3, "four legs, a plank on each pair, and a plank across them"),
        Structure("two_span_bridge", two_span, 3, "two planks end to end over three pillars"),
    ]


#: The balance tier's plank rests on one cube, its centre this far (metres) past the cube's centre: it stands
#: alone, but a cube on its far end first tips it; a cube on its near end first holds it down.
SEESAW_OFFSET = 0.02


def _balance() -> list[Structure]:
    # Near the greatest overhang four cubes reach: the centre of mass of each cube and those above it 80 % of
    # the way to the edge of the one below (the harmonic stack reaches 100 %: s/2, s/4, s/6 from the top down).
    shifts = [0.8 * EDGE / (2 * n) for n in (3, 2, 1)]
    xs = [0.0]
    for shift in shifts:
        xs.append(xs[-1] + shift)
    stair = tuple(cube(x, 0.0, k) for k, x in enumerate(xs))
    t_shape = (
        cube(0.0, 0.0, 0),
        cube(0.0, 0.0, 1),
        plank(0.0, 0.0, 2),
        cube(-PILLAR_OFFSET, 0.0, 3),
        cube(PILLAR_OFFSET, 0.0, 3),
    )
    near, far = SEESAW_OFFSET - PILLAR_OFFSET, SEESAW_OFFSET + PILLAR_OFFSET
    seesaw = (cube(0.0, 0.0, 0), plank(SEESAW_OFFSET, 0.0, 1), cube(near, 0.0, 2), cube(far, 0.0, 2))
    counterweight = (*seesaw, cube(near, 0.0, 3), cube(far, 0.0, 3))
    return [
        Structure("stair_4", stair, 4, "four cubes stepping out to the greatest overhang they allow"),
        Structure("t_shape", t_shape, 4, "a plank balanced on a two-cube column, a cube on each end"),
        Structure(
            "seesaw",
            seesaw,
            4,
            "a plank off-centre on one cube; its near end's cube must go first",
            unstable=((0, 1, 3),),
        ),
        Structure(
            "counterweight_tower",
            counterweight,
            4,
            "the seesaw with two cubes on each end: both near cubes must go on before the second far one",
            unstable=((0, 1, 3), (0, 1, 2, 3, 5)),
        ),
    ]


#: The scaffolding tier's overhang: a plank on one cube, its centre this far (metres) past the cube's centre,
#: held by cubes on its near end; alone it tips, and the cubes can only go on it once it lies there.  The
#: pillar stands this far behind the structure's origin, which keeps the prop within ``MAX_RADIUS``.
CANTILEVER_OFFSET, CANTILEVER_PILLAR = 0.035, -0.03
#: How far (metres) the scaffolding tier's prop reaches under the plank's far end: the rest of it stands out,
#: for the fingers to push it out sideways (``structures.slide_outs``).
PROP_UNDER = 0.015


def _scaffolding() -> list[Structure]:
    pillar, plank_x = CANTILEVER_PILLAR, CANTILEVER_PILLAR + CANTILEVER_OFFSET
    near = plank_x - PILLAR_OFFSET
    base = (cube(pillar, 0.0, 0), plank(plank_x, 0.0, 1))
    cantilever = (*base, cube(near, 0.0, 2), cube(near, 0.0, 3))
    # A plank across the near end holds the overhang and a cube out on it; the prop must leave before that cube
    # goes on, as the hand pushing the prop out passes where it stands.  Low: the arm reaching for the prop
    # passes over the near end, and struck a third cube stacked there.
    lookout = (*base, plank(near, 0.0, 2, np.pi / 2), cube(plank_x + EDGE / 2, 0.0, 2))
    prop_x = plank_x + PLANK_HALF + BLOCK_KINDS["prop"][0] - PROP_UNDER
    prop = (Piece("prop", (prop_x, 0.0, level(0))),)
    return [
        Structure(
            "cantilever",
            cantilever,
            5,
            "a plank overhanging one cube, held by two cubes on its near end; a prop holds its far end up until "
            "they are on, then slides out",
            scaffold=prop,
            unstable=((0, 1),),
        ),
        Structure(
            "lookout",
            lookout,
            5,
            "a plank overhanging one cube, a plank across its near end and a cube out on the overhang: the prop "
            "must slide out before that cube goes on",
            scaffold=prop,
            unstable=((0, 1),),
            order=(0, 4, 1, 2, 4, 3),
        ),
    ]


def _removal() -> list[Structure]:
    built = {s.name: s for s in (*_layouts(), *_spans(), _tower(4))}
    removals = (
        ("pyramid_top", "pyramid_6", (5,), "take the top off a 3-2-1 pyramid"),
        ("wall_middle", "wall_7", (5,), "take the middle cube out of a wall's upper course"),
        ("portal_lintel", "portal", (4,), "lift the plank off a portal"),
        ("tower_top_two", "tower_4", (2, 3), "take the top two cubes off a tower of four"),
    )
    return [
        Structure(name, built[start].pieces, 6, description, prebuilt=True, removed=removed)
        for name, start, removed, description in removals
    ]


def _suite() -> dict[str, Structure]:
    structures = [
        *(_tower(n) for n in (2, 3, 4, 6, 8)),
        *_layouts(),
        *_spans(),
        *_balance(),
        *_scaffolding(),
        *_removal(),
    ]
    return {s.name: s for s in structures}


#: Every named structure, by name, tier by tier.
SUITE: dict[str, Structure] = _suite()


def named_structure(name: str) -> Structure:
    """The suite's structure ``name``; ``ValueError`` lists the names."""
    if name not in SUITE:
        raise ValueError(f"unknown structure {name!r}; the suite holds {list(SUITE)}")
    return SUITE[name]


def as_structure(value: Structure | Mapping[str, Any] | str) -> Structure:
    """A structure from a suite name, a ``Structure`` or its mapping (``Structure.of``)."""
    return named_structure(value) if isinstance(value, str) else Structure.of(value)


def tier_structures(tier: int) -> list[Structure]:
    """The suite's structures of ``tier`` (1-6)."""
    return [s for s in SUITE.values() if s.tier == tier]
