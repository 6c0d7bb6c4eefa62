"""Rules a heightmap Q-policy can act by on top of its Q-values, chosen on selection seeds, never trained.

* ``FailureMemory`` (``PolicyAgent(avoid_failures=True)``): do not repeat, in an unchanged scene, a primitive
  that just failed there.
* ``FaceCentring`` (``PolicyAgent(centre_on_faces=True)``): move a chosen grasp or place onto the centre of the
  block face it chose, and a place on a tower onto the tower's axis.
* ``InwardPushes`` (``PolicyAgent(inward_pushes=True)``): push a tower over only towards the heightmap's
  middle, so its blocks land in view.
* ``LackingPlaces`` (``PolicyAgent(place_where_lacking=True)``): a goal-conditioned policy places only where the
  goal heightmap still stands above the scene's.

The policy still chooses the primitive, the heading and which block or tower; a rule only changes where on
that block the action lands, or forbids some actions (the best of the others is taken).  They work on encoded heightmaps (``encode_heightmap``:
channel 3 is height in millimetres, row i and column j at the ``pixel`` action grid's cell (i, j)).
"""

from __future__ import annotations

import math

import cv2
import numpy as np

from panda_grasp_env.agents.learning.heightmap_observations import GOAL_HEIGHT_RANGE, HEIGHT_RANGE

#: An acting policy does not try a primitive again within this many metres of a cell where it failed while
#: the heights there stay within ``RETRY_HEIGHT_CHANGE`` metres of what they were (``FailureMemory``).
RETRY_RADIUS = 0.012
RETRY_HEIGHT_CHANGE = 0.005
#: Primitives whose heading is a direction of travel: turned by half a turn, they are another action.
DIRECTED_PRIMITIVES = frozenset({"push"})


class FailureMemory:
    """The primitives that failed in an episode, with where, at which heading, and the heights around them.

    In an unchanged scene a greedy policy chooses the same action again and often fails the same way:
    held-out tower trials ended at the action limit retrying one grasp next to the tower.  ``excluded``
    marks the actions near an earlier failure, at its heading, whose surroundings have not changed -- the
    planned grasp agent's rule (``RETRY_DISTANCE``, ``RETRY_HEADING`` in ``agents/policies/grasping.py``) on the
    policy's grid.  A grasp or place turned by half a turn is the same action (the two fingers are alike),
    so that heading is marked too; a push turned round is not (``DIRECTED_PRIMITIVES``).  Other headings
    stay open: the tower policy's repeated failures were grasps at a wrong heading beside a block, and
    marking every heading also forbade the right grasp there (``benchmarks/failure_memory.py``).  Heights are
    all it compares: the arm may stand elsewhere after a failure, so a retry can differ.  Works on encoded
    heightmaps (``encode_heightmap``).  Used by ``PolicyAgent(avoid_failures=True)``.
    """

    def __init__(
        self,
        shape: tuple[int, int, int, int],
        cell_size: float,
        primitives: tuple[str, ...],
        height_range: float = HEIGHT_RANGE,
    ) -> None:
        """``shape``: (primitives, rotations, rows, cols) of the ``pixel`` actions; ``cell_size``: metres;
        ``primitives``: their names, in the action layout's order; ``height_range``: the metres the encoded
        height plane's 255 levels span."""
        if len(primitives) != shape[0]:
            raise ValueError(f"{len(primitives)} primitive names for an action layout of shape {shape}")
        self.shape = shape
        self.radius = max(1, round(RETRY_RADIUS / cell_size))
        self.tolerance = RETRY_HEIGHT_CHANGE / height_range * 255  # encoded height levels
        rotations = shape[1]
        self.half_turn = [rotations % 2 == 0 and name not in DIRECTED_PRIMITIVES for name in primitives]
        self.failures: list[tuple[int, list[int], slice, slice, np.ndarray]] = []

    def reset(self) -> None:
        self.failures.clear()

    def record_failure(self, action: int, observation: np.ndarray) -> None:
        """``action`` failed; ``observation`` is the encoded heightmap it was chosen on."""
        primitive, rotation, row, col = (int(i) for i in np.unravel_index(int(action), self.shape))
        rotations = self.shape[1]
        headings = [rotation, (rotation + rotations // 2) % rotations] if self.half_turn[primitive] else [rotation]
        rows = slice(max(0, row - self.radius), row + self.radius + 1)
        cols = slice(max(0, col - self.radius), col + self.radius + 1)
        self.failures.append((primitive, headings, rows, cols, observation[3, rows, cols].astype(np.int16)))

    def excluded(self, observation: np.ndarray) -> np.ndarray | None:
        """(P * R * H * W,) bool: the actions near a failure, at its heading, whose heights are as they were;
        None if none."""
        mask = np.zeros(self.shape, dtype=bool)
        for primitive, headings, rows, cols, heights in self.failures:
            if np.abs(observation[3, rows, cols].astype(np.int16) - heights).max() <= self.tolerance:
                mask[primitive, headings, rows, cols] = True
        return mask.ravel() if mask.any() else None


#: Cells within this many metres of the highest cell near a chosen action belong to the top face it chose.
FACE_DEPTH = 0.008
#: How far (metres) from the chosen cell the highest cell of the chosen face is looked for.
FACE_SEARCH = 0.016
#: A place whose face centre lies within this many metres of the tower's axis goes onto the axis.
AXIS_RADIUS = 0.02


class FaceCentring:
    """Moves a chosen grasp or place to the centre of the block top face under it; a place on a tower, to the
    tower's axis.

    Why: the network scores cells at quarter resolution (16 mm, ``HeightmapQNetwork``), so its grasps and
    places land a few millimetres off the block it chose.  An off-centre grasp holds the block off-centre,
    which the place carries over; places aimed at the top block add their errors up the tower.  On the
    selection seeds (1400000-099) the shipped 4-block builder's stalled trials were all towers whose levels
    stood more than the task's 1 cm off the base, though every block was on it, or places that fell off.

    The face is the connected set of cells within ``FACE_DEPTH`` of the highest cell within ``FACE_SEARCH``
    of the chosen cell; the action moves to its centre if its area is one block face's (a face merged with a
    touching neighbour's, or nothing near, leaves the action as it was).  A face cut by the heightmap's
    edge is centred from its inner edge and its extent along the edge (a square's axis-aligned extent is
    the same along both axes).  The tower's axis is the centre of the last face one block high that a place
    chose (the base, on the table), or the base's centre the env gave (``base``) until such a place; a
    later place whose face centre lies within ``AXIS_RADIUS`` of it goes onto the axis, so the levels'
    offsets do not add up.  (Without ``base``, a build that began on a break's leftover stack, the base and a
    block still on it, had no axis: its levels leaned 5 mm each, past the task's 1 cm.)  The heading is the
    policy's.
    """

    def __init__(
        self,
        shape: tuple[int, int, int, int],
        cell_size: float,
        primitives: tuple[str, ...],
        block_size: float,
        base: tuple[float, float] | None = None,
    ) -> None:
        """``shape``: (primitives, rotations, rows, cols) of the ``pixel`` actions; ``cell_size`` and
        ``block_size`` (the blocks' edge): metres; ``primitives``: their names, in the action layout's order;
        ``base``: the tower base's centre as (row, col) in cells (``HeightmapGrid.cell_position``), if known."""
        if len(primitives) != shape[0]:
            raise ValueError(f"{len(primitives)} primitive names for an action layout of shape {shape}")
        if not 0 < cell_size < block_size:
            raise ValueError(f"cell_size {cell_size} m must be positive and below block_size {block_size} m")
        self.shape = shape
        self.grasp = primitives.index("grasp") if "grasp" in primitives else None
        self.place = primitives.index("place") if "place" in primitives else None
        self.search = max(1, round(FACE_SEARCH / cell_size))
        self.axis_radius = AXIS_RADIUS / cell_size
        mm_per_level = HEIGHT_RANGE * 1000 / 255  # encoded height levels are millimetres
        self.depth = FACE_DEPTH * 1000 / mm_per_level
        self.lowest = 0.6 * block_size * 1000 / mm_per_level  # a block's top face stands higher
        self.one_block = 1.2 * block_size * 1000 / mm_per_level  # a face this low stands on the table
        face = (block_size / cell_size) ** 2  # cells in one face
        self.whole_face = (0.64 * face, 1.66 * face)  # its measured area, edge cells included, with margins
        self.cut_face = 0.25 * face  # the least of a face cut by the heightmap's edge
        self.axis = base  # (row, col), cells; one per build (a new FaceCentring)

    def centred(self, action: int, observation: np.ndarray) -> int:
        """``action`` moved to the centre of its face (a place on the tower: onto its axis); unchanged if it
        is not a grasp or place, or no single face lies under it.  ``observation``: the encoded heightmap."""
        primitive, rotation, row, col = (int(i) for i in np.unravel_index(int(action), self.shape))
        if primitive not in (self.grasp, self.place):
            return int(action)
        heights = observation[3]
        rows, cols = heights.shape
        r0, c0 = max(0, row - self.search), max(0, col - self.search)
        near = heights[r0 : row + self.search + 1, c0 : col + self.search + 1]
        top_row, top_col = np.unravel_index(int(np.argmax(near)), near.shape)
        top = int(near[top_row, top_col])
        if top < self.lowest:  # no block stands there
            return int(action)
        _, labels = cv2.connectedComponents((heights >= top - self.depth).astype(np.uint8))
        face_rows, face_cols = np.nonzero(labels == labels[r0 + top_row, c0 + top_col])
        centre = self._face_centre(face_rows, face_cols, rows, cols)
        if centre is None:
            return int(action)
        if primitive == self.place:
            if top <= self.one_block:
                self.axis = centre
            elif (
                self.axis is not None
                and np.hypot(centre[0] - self.axis[0], centre[1] - self.axis[1]) <= self.axis_radius
            ):
                centre = self.axis
        new_row = min(max(round(centre[0]), 0), rows - 1)
        new_col = min(max(round(centre[1]), 0), cols - 1)
        return int(np.ravel_multi_index((primitive, rotation, new_row, new_col), self.shape))

    def _face_centre(
        self, face_rows: np.ndarray, face_cols: np.ndarray, rows: int, cols: int
    ) -> tuple[float, float] | None:
        """(row, col) of a face's centre in cells, fractional; None if the cells are not one block's face."""
        row_cut = face_rows.min() == 0 or face_rows.max() == rows - 1
        col_cut = face_cols.min() == 0 or face_cols.max() == cols - 1
        area = len(face_rows)
        if (row_cut and col_cut) or area > self.whole_face[1]:
            return None
        if area < (self.cut_face if row_cut or col_cut else self.whole_face[0]):
            return None
        if not (row_cut or col_cut):
            return float(face_rows.mean()), float(face_cols.mean())
        if col_cut:  # its extent across the rows is whole: so is the face's width
            half = (face_rows.max() - face_rows.min() + 1) / 2
            inner = face_cols.max() - half + 0.5 if face_cols.min() == 0 else face_cols.min() + half - 0.5
            return (face_rows.min() + face_rows.max()) / 2, float(inner)
        half = (face_cols.max() - face_cols.min() + 1) / 2
        inner = face_rows.max() - half + 0.5 if face_rows.min() == 0 else face_rows.min() + half - 0.5
        return float(inner), (face_cols.min() + face_cols.max()) / 2


#: How far (metres) ahead of its start a push meets the tower it topples: the planned breaker's stand-off
#: (``agents/policies/towers.py`` ``PUSH_START``).
PUSH_REACH = 0.065
#: A push may head at most this far (radians) off the way from that tower to the heightmap's middle.
INWARD_CONE = math.radians(25)


class InwardPushes:
    """The pushes that would topple a tower away from the heightmap's middle, to be forbidden.

    Why: a four-block tower falls about 25 cm, and the heightmap reaches 22.4 cm from its middle, so a tower
    pushed outwards throws blocks past its edge, where a heightmap policy cannot see them: in BuildAndBreak
    the learned builder then stacked what it saw and re-placed its own top block until the action limit.
    Allowed: a push whose heading lies within ``INWARD_CONE`` of the way from the tower it meets
    (``PUSH_REACH`` ahead of its start) to the heightmap's middle, and any push meeting a tower within
    ``AXIS_RADIUS`` of the middle.  Other primitives are never forbidden.  The planned breaker's rule is
    alike (the most inward of four headings).  Chosen on BuildAndBreak's selection seeds 1400000-007
    (docs/tall-towers.md).
    """

    def __init__(self, shape: tuple[int, int, int, int], cell_size: float, primitives: tuple[str, ...]) -> None:
        """``shape``: (primitives, rotations, rows, cols) of the ``pixel`` actions; ``cell_size``: metres;
        ``primitives``: their names, in the action layout's order."""
        if len(primitives) != shape[0]:
            raise ValueError(f"{len(primitives)} primitive names for an action layout of shape {shape}")
        _, rotations, rows, cols = shape
        # World x runs along -rows and y along -columns (``HeightmapGrid.cell_centres``): (dx, dy) in cells.
        row, col = np.mgrid[:rows, :cols]
        to_middle = np.stack([row + 0.5 - rows / 2, col + 0.5 - cols / 2], -1)
        outward = np.zeros(shape, dtype=bool)
        for rotation in range(rotations):
            angle = 2 * math.pi * rotation / rotations
            heading = np.array([math.cos(angle), math.sin(angle)])
            from_tower = to_middle - PUSH_REACH / cell_size * heading
            distance = np.linalg.norm(from_tower, axis=-1)
            cosine = from_tower @ heading / np.maximum(distance, 1e-9)
            away = (cosine < math.cos(INWARD_CONE)) & (distance > AXIS_RADIUS / cell_size)
            for primitive, name in enumerate(primitives):
                if name in DIRECTED_PRIMITIVES:
                    outward[primitive, rotation] = away
        self.outward = outward.ravel()

    def excluded(self) -> np.ndarray:
        """(P * R * H * W,) bool: the pushes that head away from the heightmap's middle."""
        return self.outward


#: A place may aim where the goal stands at least this much (metres) above the scene: under half a block, so a
#: piece resting where the goal wants it, or a few millimetres off, leaves no room there (``LackingPlaces``).
LACKING_HEIGHT = 0.02
#: ... and at least this far (metres) inside the region where it does: a piece set down nearer that region's
#: edge overhangs what is built beside it, or the goal's edge (the learner's same-action radius).
LACKING_INSET = 0.012


class LackingPlaces:
    """The places that would put a piece where the goal heightmap does not stand above the scene, to be forbidden.

    Why: a goal-conditioned builder's failed places mostly landed a whole block above or below the nearest
    target of their kind (on a built piece, or on a loose one), or a centimetre or two off across it
    (``benchmarks/builder_failures.py``, docs/structures.md).  Allowed: a place at a cell where the goal stands
    at least ``LACKING_HEIGHT`` above the scene, ``LACKING_INSET`` or more inside the region where it does.
    Where no cell is, every place stays allowed (the rule then does not choose for the policy); other
    primitives are never forbidden.  Works on encoded heightmaps with a goal plane (``GoalHeightmap``:
    channel 3 the scene's height, channel ``goal_plane`` the goal's, both over ``GOAL_HEIGHT_RANGE``)."""

    def __init__(
        self, shape: tuple[int, int, int, int], cell_size: float, primitives: tuple[str, ...], goal_plane: int
    ) -> None:
        """``shape``: (primitives, rotations, rows, cols) of the ``pixel`` actions; ``cell_size``: metres;
        ``primitives``: their names, in the action layout's order; ``goal_plane``: the goal's channel."""
        if len(primitives) != shape[0]:
            raise ValueError(f"{len(primitives)} primitive names for an action layout of shape {shape}")
        if "place" not in primitives:
            raise ValueError(f"LackingPlaces needs a place primitive, got {primitives}")
        self.shape, self.place, self.goal_plane = shape, primitives.index("place"), goal_plane
        inset = round(LACKING_INSET / cell_size)
        self.kernel = np.ones((2 * inset + 1, 2 * inset + 1), np.uint8)

    def excluded(self, observation: np.ndarray) -> np.ndarray:
        """(P * R * H * W,) bool: the places outside the inset region where the goal still stands above the
        scene in ``observation`` (C, H, W), encoded."""
        lacking = (observation[self.goal_plane].astype(float) - observation[3]) * (GOAL_HEIGHT_RANGE / 255.0)
        room = cv2.erode((lacking >= LACKING_HEIGHT).astype(np.uint8), self.kernel, borderType=cv2.BORDER_REPLICATE)
        excluded = np.zeros(self.shape, dtype=bool)
        if room.any():
            excluded[self.place] = ~room.astype(bool)[None]
        return excluded.ravel()
