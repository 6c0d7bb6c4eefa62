"""A top-down primitive's full parameter vector from where an agent points: (x, y) and heading, with the height
read from the scene when the agent does not give one.

Positions are metres in the world frame, 0 = the table top; headings are radians about world z (the closing
axis for grasp and place, the direction of motion for push and impulse).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from panda_grasp_env.primitives.top_down import MIN_GRASP_HEIGHT
from panda_grasp_env.sim.workcell import Workcell

#: Where a grasp closes below the top surface it aims at, metres.
GRASP_DEPTH = 0.02
#: With push faces (``SceneConfig.push_faces``), a push through nothing taller than this (metres) runs as low as
#: the fingers go (``MIN_GRASP_HEIGHT``: fingertips 5 mm above the table, the flat push faces from 7.5 mm up),
#: below the height w / (2 mu) above which a pushed object of width w and table friction mu tips over its leading
#: edge instead of sliding (7.5 mm for a 3 cm cube at the largest friction, 2, that objects take; 25 mm for a
#: 5 cm block at 1).
LOW_PUSH_MAX_HEIGHT = 0.075
#: Heights (metres) between which a push through something taller runs: half its height, so that a tower
#: topples rather than its bottom block sliding out.
PUSH_HEIGHT_RANGE = (0.03, 0.12)


@dataclass(frozen=True)
class PrimitiveSettings:
    """The primitives an agent chooses from (in action-layout order), whether it gives heights (``with_z``),
    and the parameters it does not choose: push length (metres) and impulse (N s)."""

    primitives: tuple[str, ...]
    with_z: bool = False
    push_distance: float = 0.1  # metres (VPG)
    impulse_magnitude: float = 0.06  # N s


def surface_height(cell: Workcell, x: float, y: float, exclude_body: int = -1, radius: float = 0.01) -> float:
    """Height of the highest table or object surface within ``radius`` metres of world (x, y), metres (0 = table
    top), leaving out body ``exclude_body``.

    Ray casts straight down through a 3 x 3 pattern; the robot is not seen.
    """
    return max(
        cell.surface_below(x + dx, y + dy, exclude_body)[0]
        for dx in (-radius, 0.0, radius)
        for dy in (-radius, 0.0, radius)
    )


def primitive_parameters(
    cell: Workcell, settings: PrimitiveSettings, name: str, x: float, y: float, yaw: float, z: float | None
) -> list[float]:
    """Full parameter vector of primitive ``name`` at world (x, y) with heading ``yaw``; ``z=None`` picks the
    height (metres) from the scene.

    Automatic heights: ``grasp`` closes ``GRASP_DEPTH`` below the surface at
    (x, y); ``place`` puts the object on that surface; ``push`` runs at half
    the height of what lies in its path + 1 cm (within ``PUSH_HEIGHT_RANGE``: a
    tower topples), or, with push faces, as low as the fingers go through
    things up to ``LOW_PUSH_MAX_HEIGHT`` tall (they slide rather than tip);
    ``impulse`` strikes the top object at (x, y).
    """
    held = cell.robot.body_between_fingers()
    if name == "grasp":
        z = max(surface_height(cell, x, y) - GRASP_DEPTH, MIN_GRASP_HEIGHT) if z is None else z
        return [x, y, z, yaw]
    if name == "place":
        z = surface_height(cell, x, y, exclude_body=-1 if held is None else held, radius=0.015) if z is None else z
        return [x, y, z, yaw]
    if name == "push":
        if z is None:
            ahead = np.linspace(0.0, settings.push_distance, 6)
            heights = [surface_height(cell, x + d * np.cos(yaw), y + d * np.sin(yaw)) for d in ahead]
            tallest = max(heights)
            low = cell.config.push_faces and tallest <= LOW_PUSH_MAX_HEIGHT
            z = MIN_GRASP_HEIGHT if low else float(np.clip(tallest / 2 + 0.01, *PUSH_HEIGHT_RANGE))
        return [x, y, z, yaw, settings.push_distance]
    if name == "impulse":
        z = surface_height(cell, x, y) - 0.02 if z is None else z
        return [x, y, z, yaw, settings.impulse_magnitude]
    raise ValueError(f"unknown primitive {name!r}")
