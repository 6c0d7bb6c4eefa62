"""Random structures for training: the motifs of tiers 1-4, sized at random, never one of the named suite's.

``random_structure(rng, max_pieces, tiers)`` draws a tier, then one of its motifs that fits the block budget,
then the motif's sizes:

* tier 1, towers: 2-7 cubes whose levels shift by up to 4 mm and turn by up to 0.2 rad (the suite's heights,
  2, 3, 4, 6 and 8, resemble its towers: drawn again, so 5 and 7 remain);
* tier 2, layouts: a row of 2-4 cubes at a random pitch, an L with arms of 2-3 cubes, or a two-course wall
  of 2-3 cubes with one fewer on their joints;
* tier 3, spans: a plank across two pillars of 1-2 cubes at a random spacing, with or without a cube on it;
* tier 4, balance: a stair of 2-4 cubes stepping out to 30-80 % of the greatest overhang they allow, a plank
  balanced on a column with a cube towards each end, or a plank off-centre on a cube whose near end's cube
  must go on before its far end's (``Structure.unstable`` says which partial build falls).

A draw that resembles a suite structure (``resembles``: every horizontal distance between centres and every
height within ``RESEMBLANCE``, which any copy of it moved in the plane meets) is drawn again, so a policy trained here has never seen a
test structure.  Frames and units as in ``structures``: metres, radians, the structure's frame on the table.
"""

from __future__ import annotations

from collections.abc import Callable, Sequence

import numpy as np

from panda_grasp_env.model.structure_suite import EDGE, PILLAR_OFFSET, SUITE, cube, level, plank
from panda_grasp_env.model.structures import Piece, Structure

#: The tiers whose motifs the generator composes (the default), and the most pieces a structure may have.
GENERATED_TIERS, MAX_PIECES = (1, 2, 3, 4), 8
#: Two structures resemble each other when their sorted horizontal distances between centres and their sorted
#: heights differ by less than this (metres): twice the task's in-place tolerance, so a copy of a suite
#: structure moved in the plane, each piece within that tolerance, always does.
RESEMBLANCE = 0.02
#: Draws before giving up (a budget no motif resembling nothing in the suite fits).
DRAWS = 100

Motif = Callable[[np.random.Generator, int], Structure]


def _centred(pieces: Sequence[Piece]) -> tuple[Piece, ...]:
    """``pieces`` shifted so that their footprint's centre lies at the origin."""
    xy = np.array([p.position[:2] for p in pieces])
    centre = (xy.min(axis=0) + xy.max(axis=0)) / 2
    return tuple(
        Piece(p.kind, (p.position[0] - centre[0], p.position[1] - centre[1], p.position[2]), p.yaw) for p in pieces
    )


def tower(rng: np.random.Generator, budget: int) -> Structure:
    n = int(rng.integers(2, min(7, budget) + 1))
    shifts, turns = rng.uniform(-0.004, 0.004, (n, 2)), rng.uniform(-0.2, 0.2, n)
    return Structure("random_tower", tuple(Piece("cube", (*shifts[k], level(k)), turns[k]) for k in range(n)), 1)


def row(rng: np.random.Generator, budget: int) -> Structure:
    n = int(rng.integers(2, min(4, budget) + 1))
    pitch = rng.uniform(0.058, 0.08)
    return Structure("random_row", tuple(cube((k - (n - 1) / 2) * pitch, 0.0, 0) for k in range(n)), 2)


def ell(rng: np.random.Generator, budget: int) -> Structure:
    along, across = (int(v) for v in rng.integers(2, 4, 2))
    while along + across - 1 > budget:
        along, across = max(2, along - 1), max(2, across - 1)
    pitch = rng.uniform(0.056, 0.07)
    cells = [(k, 0) for k in range(along)] + [(0, k) for k in range(1, across)]
    return Structure("random_ell", _centred([cube(x * pitch, y * pitch, 0) for x, y in cells]), 2)


def wall(rng: np.random.Generator, budget: int) -> Structure:
    n = int(rng.integers(2, min(3, (budget + 1) // 2) + 1))
    pitch = rng.uniform(0.055, 0.06)  # gaps of 5-10 mm: a cube on a joint rests 2-2.5 cm on each side
    bottom = [cube((k - (n - 1) / 2) * pitch, 0.0, 0) for k in range(n)]
    top = [cube((k - (n - 2) / 2) * pitch, 0.0, 1) for k in range(n - 1)]
    return Structure("random_wall", tuple(bottom + top), 2)


def span(rng: np.random.Generator, budget: int) -> Structure:
    height = int(rng.integers(1, 3)) if budget >= 5 else 1
    offset = rng.uniform(PILLAR_OFFSET - 0.012, PILLAR_OFFSET)
    pillars = [cube(x, 0.0, k) for x in (-offset, offset) for k in range(height)]
    topped = len(pillars) + 2 <= budget and rng.random() < 0.5
    on_top = [cube(rng.uniform(-0.02, 0.02), 0.0, height + 1)] if topped else []
    return Structure("random_span", tuple([*pillars, plank(0.0, 0.0, height), *on_top]), 3)


def stair(rng: np.random.Generator, budget: int) -> Structure:
    n = int(rng.integers(2, min(4, budget) + 1))
    reach = rng.uniform(0.3, 0.8)  # of the harmonic stack's: each step s/2, s/4, s/6 ... from the top down
    xs = np.concatenate([[0.0], np.cumsum([reach * EDGE / (2 * k) for k in range(n - 1, 0, -1)])])
    return Structure("random_stair", _centred([cube(x, 0.0, k) for k, x in enumerate(xs)]), 4)


def tee(rng: np.random.Generator, budget: int) -> Structure:
    height = int(rng.integers(1, 3)) if budget >= 5 else 1
    column = [cube(0.0, 0.0, k) for k in range(height)]
    ends = [cube(side * rng.uniform(PILLAR_OFFSET - 0.02, PILLAR_OFFSET), 0.0, height + 1) for side in (-1, 1)]
    return Structure("random_tee", tuple([*column, plank(0.0, 0.0, height), *ends]), 4)


def seesaw(rng: np.random.Generator, budget: int) -> Structure:
    """A plank whose centre lies 17-20 mm past its cube's: it stands alone and with a cube on each end, but a
    cube on its far end alone tips it (the centre of mass ~29 mm out, past the cube's 25 mm half-width)."""
    offset = rng.uniform(0.017, 0.02)
    near, far = cube(offset - PILLAR_OFFSET, 0.0, 2), cube(offset + PILLAR_OFFSET, 0.0, 2)
    pieces = [cube(0.0, 0.0, 0), plank(offset, 0.0, 1), near]
    if budget >= 4 and rng.random() < 0.7:
        return Structure("random_seesaw", _centred([*pieces, far]), 4, unstable=((0, 1, 3),))
    return Structure("random_seesaw", _centred(pieces), 4)


#: Each generated tier's motifs, and the fewest pieces each needs.
MOTIFS: dict[int, tuple[tuple[Motif, int], ...]] = {
    1: ((tower, 2),),
    2: ((row, 2), (ell, 3), (wall, 3)),
    3: ((span, 3),),
    4: ((stair, 2), (tee, 4), (seesaw, 3)),
}


def _signature(pieces: Sequence[Piece]) -> tuple[tuple[str, ...], np.ndarray, np.ndarray]:
    """What a rigid motion in the table plane keeps: the sorted kinds, the sorted horizontal distances between
    piece centres and the sorted heights of the centres (metres)."""
    centres = np.array([p.position for p in pieces])
    pairs = np.triu_indices(len(centres), 1)
    across = np.linalg.norm(centres[:, None, :2] - centres[None, :, :2], axis=2)[pairs]
    return tuple(sorted(p.kind for p in pieces)), np.sort(across), np.sort(centres[:, 2])


def resembles(pieces: Sequence[Piece], other: Sequence[Piece]) -> bool:
    """Whether ``pieces`` could be ``other`` moved in the plane with every piece within half of ``RESEMBLANCE``:
    a necessary condition (their signatures agree within ``RESEMBLANCE``), so pieces that do not resemble
    ``other`` are surely not a copy of them."""
    kinds, across, heights = _signature(pieces)
    other_kinds, other_across, other_heights = _signature(other)
    if kinds != other_kinds:
        return False
    return bool(
        np.all(np.abs(across - other_across) < RESEMBLANCE) and np.all(np.abs(heights - other_heights) < RESEMBLANCE)
    )


def check_tiers(tiers: object) -> tuple[int, ...]:
    """``tiers`` (one tier or a sequence of them) as a sorted tuple of ``GENERATED_TIERS``; ``ValueError``
    naming the value otherwise."""
    values = [tiers] if isinstance(tiers, (int, np.integer)) and not isinstance(tiers, bool) else tiers
    if (
        not isinstance(values, (list, tuple))
        or not values
        or not all(
            isinstance(t, (int, np.integer)) and not isinstance(t, bool) and t in GENERATED_TIERS for t in values
        )
    ):
        raise ValueError(f"tiers must be one of {GENERATED_TIERS} or a non-empty list of them, got {tiers!r}")
    return tuple(sorted({int(t) for t in values}))


def random_structure(
    rng: np.random.Generator, max_pieces: int, tiers: int | Sequence[int] = GENERATED_TIERS
) -> Structure:
    """A structure of at most ``max_pieces`` pieces (2-8) from a motif of one of ``tiers`` (drawn uniformly
    among the tiers, then among the tier's motifs that fit), resembling no suite structure."""
    tiers = check_tiers(tiers)
    if not (isinstance(max_pieces, (int, np.integer)) and 2 <= max_pieces <= MAX_PIECES):
        raise ValueError(f"max_pieces must be an int in [2, {MAX_PIECES}], got {max_pieces!r}")
    for _ in range(DRAWS):
        tier = tiers[int(rng.integers(len(tiers)))]
        fitting = [motif for motif, fewest in MOTIFS[tier] if fewest <= max_pieces]
        if not fitting:
            continue
        structure = fitting[int(rng.integers(len(fitting)))](rng, int(max_pieces))
        if not any(resembles(structure.goal, named.goal) for named in SUITE.values()):
            return structure
    raise ValueError(f"no structure of tiers {tiers} with at most {max_pieces} pieces resembles no suite structure")
