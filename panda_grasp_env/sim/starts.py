"""Where the hand starts a low-level episode: the ready pose, and the start curricula (``PandaEnv(start_*=...)``).

All positions are of the grasp site in world metres; the hand points down at ``HOME_YAW``.  ``bounds`` is
the low-level workspace ((x0, x1), (y0, y1), (z0, z1)) metres (``actions.LOW_LEVEL_BOUNDS``): a start never
puts the grasp site below its floor, and ``behind_object`` never outside it.
"""

from __future__ import annotations

from collections.abc import Callable

import numpy as np

from panda_grasp_env.model.robot import FINGER_CLOSED, FINGER_OPEN, HOME_YAW
from panda_grasp_env.sim.workcell import Workcell

#: Low-level modes start each episode with the hand here (x, y metres), pointing down, this high above
#: the tallest object (at least ``READY_MIN_HEIGHT``): close to the work, like Fetch and panda-gym.
READY_XY = (0.45, 0.0)
READY_CLEARANCE = 0.08
READY_MIN_HEIGHT = 0.15
#: ``start_in_hand``: an object that moved more than this (metres) while the fingers closed on it was not
#: cleanly held; the episode starts normally instead.
HOLD_START_DRIFT = 0.015


def ready_position(cell: Workcell) -> np.ndarray:
    """The usual start of the grasp site: at ``READY_XY``, ``READY_CLEARANCE`` above the tallest object's top
    (its centre plus bounding radius) and at least ``READY_MIN_HEIGHT`` high."""
    model, data = cell.model, cell.data
    tops = [data.xpos[b][2] + model.geom_rbound[model.body_geomadr[b]] for b in cell.object_ids]
    tallest = max((float(top) for top in tops), default=0.0)
    return np.array([*READY_XY, max(READY_MIN_HEIGHT, tallest + READY_CLEARANCE)])


def start_in_hand(
    cell: Workcell,
    body: int,
    ready: np.ndarray,
    rng: np.random.Generator,
    bounds: np.ndarray,
    goal: Callable[[], np.ndarray],
) -> bool:
    """Close the fingers on ``body`` where it lies (grasp site at its centre, the low-level heading) and
    restart the clock.  If the open hand put there touches it (too wide for the fingers at this heading)
    or closing does not hold it, put the object and the hand back (the hand at ``ready``, open) and
    return False."""
    position, orientation = cell.data.xpos[body].copy(), cell.data.xquat[body].copy()
    centre = np.array([*position[:2], max(position[2], bounds[2, 0])])
    cell.motion.teleport_hand(centre, HOME_YAW)
    held = not cell.touches_robot(body)  # the open hand must be around the object, not in it
    if held:
        cell.actuate_gripper(close=True, timeout=0.5)
        held = body in cell.robot.bodies_between_fingers()
    if not held or np.linalg.norm(cell.data.xpos[body] - position) > HOLD_START_DRIFT:
        cell.set_body_pose(body, position, orientation)
        cell.robot.teleport_fingers(FINGER_OPEN)
        cell.motion.teleport_hand(ready, HOME_YAW)
        held = False
    cell.settle(0.0)
    return held


def start_above_object(
    cell: Workcell,
    body: int,
    ready: np.ndarray,
    rng: np.random.Generator,
    bounds: np.ndarray,
    goal: Callable[[], np.ndarray],
) -> bool:
    """Put the open hand straight above ``body``, the grasp site anywhere (uniform) from the object's centre
    up to the height of ``ready``; if it touches the object there, back to ``ready`` and return False."""
    position = cell.data.xpos[body]
    low = max(position[2], bounds[2, 0])
    cell.motion.teleport_hand(np.array([*position[:2], low + rng.random() * (ready[2] - low)]), HOME_YAW)
    if cell.touches_robot(body):
        cell.motion.teleport_hand(ready, HOME_YAW)
        return False
    return True


def start_behind_object(
    cell: Workcell,
    body: int,
    ready: np.ndarray,
    rng: np.random.Generator,
    bounds: np.ndarray,
    goal: Callable[[], np.ndarray],
) -> bool:
    """Put the hand at ``body``'s height on the far side from ``goal()`` (the task's desired goal): first the
    nearest grasp-site distance (1 cm steps out from the object's bounding radius) at which it does not
    touch the object, then 0-10 cm (uniform) further back.  If no such place is found within 8 cm, or the
    place is outside ``bounds``, back to ``ready`` and return False.  The fingers start closed."""
    position = cell.data.xpos[body].copy()
    away = position[:2] - goal()[:2]
    away /= max(float(np.linalg.norm(away)), 1e-9)
    height = max(position[2], bounds[2, 0])
    radius = float(cell.model.geom_rbound[cell.model.body_geomadr[body]])

    def site(distance: float) -> np.ndarray:
        return np.array([*(position[:2] + distance * away), height])

    further = 0.1 * rng.random()
    cell.robot.teleport_fingers(FINGER_CLOSED)  # a fist: a pushed block cannot slip between the fingers
    for clear in np.arange(radius, radius + 0.085, 0.01):
        start = site(clear + further)
        inside = np.all(start >= bounds[:, 0]) and np.all(start <= bounds[:, 1])
        cell.motion.teleport_hand(site(clear), HOME_YAW)
        if not cell.touches_robot(body):
            if inside:
                cell.motion.teleport_hand(start, HOME_YAW)
                return True
            break
    cell.robot.teleport_fingers(FINGER_OPEN)
    cell.motion.teleport_hand(ready, HOME_YAW)
    return False


#: Each start state (``Task.start_states``) and how the hand gets there.
STARTS = {"in_hand": start_in_hand, "above_object": start_above_object, "behind_object": start_behind_object}


def start_hand(
    cell: Workcell,
    curriculum: dict[str, float],
    start_object: Callable[[Workcell], int],
    rng: np.random.Generator,
    bounds: np.ndarray,
    goal: Callable[[], np.ndarray],
) -> str:
    """Put the hand where a low-level episode starts: at ``ready_position``, pointing down at ``HOME_YAW``;
    then, with a ``curriculum`` (start state -> probability; the rest: ``ready``), one draw of a start state
    relative to the task's start object (``start_object(cell)``).  Returns the state the episode starts in,
    ``ready`` where the drawn one could not be reached.  Without a curriculum nothing is drawn from ``rng``."""
    ready = ready_position(cell)
    cell.motion.teleport_hand(ready, HOME_YAW)
    if not curriculum:
        return "ready"
    body, draw = start_object(cell), rng.random()
    for state, probability in curriculum.items():
        if draw < probability:
            return state if STARTS[state](cell, body, ready, rng, bounds, goal) else "ready"
        draw -= probability
    return "ready"
