"""The Grasp task's scenes: how each episode's objects come to lie on the table.

One generator per kind of scene; the task's options choose it (``grasp_layout``), and through them its ids:

* ``ScatteredLayout``: the objects set down apart (``PandaGrasp-v0``, ``PandaGraspMesh-v0``);
* ``HeapLayout``: dropped into a heap in the middle of the workspace, as VPG does (``clutter``:
  ``PandaGraspClutter-v0``, ``PandaGraspMeshClutter-v0``);
* ``AdversarialLayout`` and ``RandomPackedLayout``: objects packed so tightly that no grasp fits until a push
  frees one (``packed``: the hand-designed ``packed_layouts.ADVERSARIAL_LAYOUTS`` on
  ``PandaGraspAdversarial-v0``, random packed grids on ``PandaGraspPacked-v0``);
* ``MixedLayout``: a heap in a share of the episodes, a packed layout in the others (``heap_share``:
  ``PandaGraspMixed-v0``).

World frame, metres, radians.  Every draw comes from the episode's ``rng`` in a fixed order: the same seed lays
out the same scene.
"""

from __future__ import annotations

from abc import ABC, abstractmethod
from dataclasses import dataclass
from typing import Any

import numpy as np

from panda_grasp_env.model.objects import ObjectShape, ObjectSpec
from panda_grasp_env.sim.workcell import SPAWN_REGION, Workcell
from panda_grasp_env.tasks.base import check_option
from panda_grasp_env.tasks.packed_layouts import (
    ADVERSARIAL_LAYOUTS,
    CENTRE_JITTER,
    CUBE,
    TURN_JITTER,
    jittered,
    random_packed_layout,
)

#: VPG drops its clutter into the middle of the workspace; a 0.2 m square here (world x, y bounds, metres).
CLUTTER_REGION = np.array([[0.4, 0.6], [-0.1, 0.1]])
#: Objects in a heap that stands in for a packed layout (``MixedLayout``): as many as ``clutter`` drops.
HEAP_OBJECTS = 10
#: Where packed layouts stand (world xy, metres): the hand-designed ones at the centre (then jittered),
#: random ones anywhere in the square around it.
PACKED_CENTRE, RANDOM_PACKED_REGION = np.array([0.5, 0.0]), np.array([[0.45, 0.55], [-0.05, 0.05]])
#: The (kind, geom size) of the object slots a packed layout leaves unused (parked).
SPARE_SHAPE = CUBE
#: Widest an object may be across the fingers of a hand that cannot turn (metres): the 73 mm opening
#: between the pads less 6.5 mm each side for the approach's error.  Every default size fits at some yaw.
HAND_FIT_WIDTH = 0.06


@dataclass(frozen=True)
class LaidOut:
    """What a layout put on the table: the objects' shapes in object-slot order, and the name the reset's
    ``info["layout"]`` reports (None: the scene has no name, and the info no ``layout`` key)."""

    shapes: list[ObjectShape]
    name: str | None = None


class GraspLayout(ABC):
    """A generator of Grasp scenes."""

    @abstractmethod
    def lay_out(
        self, cell: Workcell, rng: np.random.Generator, specs: list[ObjectSpec], hand_yaw: float | None
    ) -> LaidOut:
        """Put an episode's objects on the cleared table of ``cell`` and let them settle.

        ``specs``: the object specs to draw from, one per object slot (layouts that bring their own objects
        ignore them); ``hand_yaw``: the heading (radians, world) of a hand that cannot turn
        (``Task.fixed_hand_yaw``), None where actions choose the heading."""


def set_shapes(cell: Workcell, shapes: list[ObjectShape]) -> None:
    """Give the first object slots ``shapes``; the slots left over get one fixed shape (``SPARE_SHAPE``) and stay
    parked: what they held in the previous episode must not show in this one's state."""
    spare = ObjectShape(*SPARE_SHAPE)
    cell.set_object_shapes(
        {int(body): shapes[i] if i < len(shapes) else spare for i, body in enumerate(cell.object_ids)}
    )
    for body in cell.object_ids[len(shapes) :]:
        cell.park(int(body))


def fitting_yaw(shape: ObjectShape, yaw: float, hand_yaw: float, rng: np.random.Generator) -> float:
    """``yaw`` if the shape resting at it is at most ``HAND_FIT_WIDTH`` wide across the fingers of a hand
    at heading ``hand_yaw`` (radians, world; the fingers close along that heading), else a yaw drawn
    uniformly among those where it fits (the narrowest of the draws if none does: sizes past the defaults)."""
    if shape.width_across(yaw, hand_yaw) <= HAND_FIT_WIDTH:
        return yaw
    draws = rng.uniform(-np.pi / 2, np.pi / 2, 256)
    widths = np.array([shape.width_across(y, hand_yaw) for y in draws])
    fits = np.flatnonzero(widths <= HAND_FIT_WIDTH)
    return float(draws[fits[0]] if fits.size else draws[np.argmin(widths)])


class ScatteredLayout(GraspLayout):
    """One object per spec, set down resting at its spec's yaw anywhere in ``SPAWN_REGION``, 4 cm clear of the
    others; for a hand that cannot turn, turned to fit between its fingers (``fitting_yaw``)."""

    def lay_out(
        self, cell: Workcell, rng: np.random.Generator, specs: list[ObjectSpec], hand_yaw: float | None
    ) -> LaidOut:
        shapes = [spec.sample(rng) for spec in specs]
        set_shapes(cell, shapes)
        placed: list[tuple[np.ndarray, float]] = []
        for body, shape, spec in zip(cell.object_ids, shapes, specs):
            for _ in range(1000):  # rejection sampling; the region holds 30 small objects easily
                xy = np.array([rng.uniform(*SPAWN_REGION[0]), rng.uniform(*SPAWN_REGION[1])])
                if all(np.linalg.norm(xy - p) >= shape.bounding_radius + r + 0.04 for p, r in placed):
                    break
            placed.append((xy, shape.bounding_radius))
            yaw = spec.sample_yaw(rng)
            if hand_yaw is not None:  # a hand that cannot turn must fit around the object
                yaw = fitting_yaw(shape, yaw, hand_yaw, rng)
            cell.set_body_pose(body, [*xy, shape.resting_half_height + 0.001], shape.resting_quaternion(yaw))
        # A mesh set down at a drawn orientation tips onto a face: give it time to come to rest.
        cell.settle(1.0 if any(shape.kind == "mesh" for shape in shapes) else 0.3)
        return LaidOut(shapes)


@dataclass(frozen=True)
class HeapLayout(GraspLayout):
    """The first ``objects`` specs' objects dropped into ``CLUTTER_REGION`` at random headings, one above the
    other (staggered 6 cm), so that they fall onto each other into a heap (VPG's clutter)."""

    objects: int

    def lay_out(
        self, cell: Workcell, rng: np.random.Generator, specs: list[ObjectSpec], hand_yaw: float | None
    ) -> LaidOut:
        shapes = [spec.sample(rng) for spec in specs[: self.objects]]
        set_shapes(cell, shapes)
        for level, (body, shape) in enumerate(zip(cell.object_ids, shapes)):
            xy = [rng.uniform(*CLUTTER_REGION[0]), rng.uniform(*CLUTTER_REGION[1])]
            height = shape.bounding_radius + 0.01 + 0.06 * level
            cell.set_body_pose(body, [*xy, height], shape.resting_quaternion(rng.uniform(-np.pi, np.pi)))
        cell.settle(1.5)
        return LaidOut(shapes)


def _place_packed(cell: Workcell, placed: list[tuple[ObjectShape, np.ndarray, float]]) -> list[ObjectShape]:
    """Set ``placed`` (shape, world xy, yaw) down resting on the table, the unused slots parked; their shapes."""
    shapes = [shape for shape, _, _ in placed]
    set_shapes(cell, shapes)
    for body, (shape, xy, yaw) in zip(cell.object_ids, placed):
        cell.set_body_pose(body, [*xy, shape.resting_half_height + 0.0005], shape.resting_quaternion(yaw))
    cell.settle(0.3)
    return shapes


@dataclass(frozen=True)
class AdversarialLayout(GraspLayout):
    """One of the hand-designed ``ADVERSARIAL_LAYOUTS`` (``index``; None: drawn per episode), at
    ``PACKED_CENTRE`` moved by up to ``CENTRE_JITTER`` and turned by up to ``TURN_JITTER``, each object
    jittered (``packed_layouts.jittered``); named after the layout."""

    index: int | None = None

    def lay_out(
        self, cell: Workcell, rng: np.random.Generator, specs: list[ObjectSpec], hand_yaw: float | None
    ) -> LaidOut:
        index = self.index if self.index is not None else int(rng.integers(len(ADVERSARIAL_LAYOUTS)))
        name = list(ADVERSARIAL_LAYOUTS)[index]
        centre = PACKED_CENTRE + rng.uniform(-CENTRE_JITTER, CENTRE_JITTER, 2)
        placed = jittered(ADVERSARIAL_LAYOUTS[name], rng, centre, rng.uniform(-TURN_JITTER, TURN_JITTER))
        return LaidOut(_place_packed(cell, placed), name)


class RandomPackedLayout(GraspLayout):
    """A random packed grid (``packed_layouts.random_packed_layout``, for training) anywhere in
    ``RANDOM_PACKED_REGION`` at any heading; named ``"random"``."""

    def lay_out(
        self, cell: Workcell, rng: np.random.Generator, specs: list[ObjectSpec], hand_yaw: float | None
    ) -> LaidOut:
        layout = random_packed_layout(rng)
        centre = rng.uniform(RANDOM_PACKED_REGION[:, 0], RANDOM_PACKED_REGION[:, 1])
        placed = jittered(layout, rng, centre, rng.uniform(-np.pi, np.pi))
        return LaidOut(_place_packed(cell, placed), "random")


@dataclass(frozen=True)
class MixedLayout(GraspLayout):
    """With probability ``heap_share`` per episode a ``heap`` (named ``"heap"``), else the ``packed`` layout: a
    policy trained on packed layouts alone never sees objects near the workspace's edge or lying on others."""

    heap_share: float
    packed: GraspLayout
    heap: HeapLayout

    def lay_out(
        self, cell: Workcell, rng: np.random.Generator, specs: list[ObjectSpec], hand_yaw: float | None
    ) -> LaidOut:
        if rng.random() < self.heap_share:
            return LaidOut(self.heap.lay_out(cell, rng, specs, hand_yaw).shapes, "heap")
        return self.packed.lay_out(cell, rng, specs, hand_yaw)


def adversarial_layout_index(packed: str | None, layout: Any) -> int | None:
    """The index in ``ADVERSARIAL_LAYOUTS`` of the Grasp task's ``layout`` option (an index or a name, given
    with ``packed="adversarial"`` only), or None; ``ValueError`` naming the option."""
    if layout is None:
        return None
    names = list(ADVERSARIAL_LAYOUTS)
    check_option("layout", layout, packed == "adversarial", 'given with packed="adversarial" only')
    if isinstance(layout, str):
        check_option("layout", layout, layout in names, f"an index or one of {names}")
        return names.index(layout)
    valid = isinstance(layout, (int, np.integer)) and not isinstance(layout, bool) and 0 <= layout < len(names)
    check_option("layout", layout, valid, f"an index in [0, {len(names) - 1}] or one of {names}")
    return int(layout)


def grasp_layout(
    n_objects: int, clutter: bool, packed: str | None, layout_index: int | None, heap_share: float
) -> GraspLayout:
    """The generator the Grasp task's (checked) options choose: a packed layout (``packed``: ``"adversarial"``,
    at ``layout_index`` if given, or ``"random"``), mixed with ``HEAP_OBJECTS``-object heaps where
    ``heap_share`` > 0; else a heap of ``n_objects`` (``clutter``) or the objects scattered."""
    if packed is None:
        return HeapLayout(n_objects) if clutter else ScatteredLayout()
    chosen = AdversarialLayout(layout_index) if packed == "adversarial" else RandomPackedLayout()
    return MixedLayout(heap_share, chosen, HeapLayout(HEAP_OBJECTS)) if heap_share > 0 else chosen
